"""``EmulatedPanTilt``: the Dynamixel driver on a built-in servo emulator (``emulated_pan_tilt``).

The gimbal of the simulated closed loop: the real :class:`~aes_planner.drivers.dynamixel.DynamixelPanTilt`
code path (dynamixel-sdk, Protocol 2.0 on a pty) against a
:class:`~aes_planner.drivers.emulator.ServoEmulator` it starts on ``connect()``.

Faults can be injected mid-run, while the driver is in use from other threads, through the
methods of :class:`~aes_planner.devices.GimbalFaults` (the same names on
:class:`~aes_planner.drivers.sim_gimbal.SimPanTilt`)::

    gimbal.inject_comm_faults(lost=2, corrupt=1)        # the next replies on the bus
    gimbal.inject_comm_faults(delayed=1, delay_s=0.2)   # a late reply
    gimbal.inject_hardware_error("tilt", "overload")    # the servo's alert: torque off, latched
    gimbal.inject_stall("pan")                           # an obstruction: waits time out
    gimbal.vanish_port(); gimbal.restore_port()          # the USB cable pulled and plugged back
    gimbal.clear_faults()                                # back to a clean bus (errors stay latched)

What the driver does about each is the driver's business (retries, torque off, reconnect); see
:mod:`aes_planner.drivers.dynamixel`. The pty sits behind a symlink in a private folder (or at
``port`` when given), so that the driver finds the emulator again after ``restore_port()``.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
from pathlib import Path

from aes_planner.drivers.dynamixel import DynamixelPanTilt
from aes_planner.drivers.dynamixel_config import JOINTS, EmulatedPanTiltConfig
from aes_planner.drivers.dynamixel_models import HARDWARE_ERROR_BITS

__all__ = ["EmulatedPanTilt", "EmulatedPanTiltConfig"]


class EmulatedPanTilt(DynamixelPanTilt):
    """:class:`DynamixelPanTilt` on a :class:`~aes_planner.drivers.emulator.ServoEmulator` that it
    starts on ``connect()`` and stops on ``disconnect()``: the gimbal of the simulated closed loop.
    ``emulator`` is the running emulator (None while disconnected), for inspection; inject faults
    through the methods below (see the module docstring)."""

    config_class = EmulatedPanTiltConfig

    def __init__(self, config: EmulatedPanTiltConfig):
        super().__init__(config)
        self._link = config.port or None
        self._link_dir: str | None = None
        self.emulator = None
        self._clock = None  # the servos' time (None: the machine's); see use_clock

    def use_clock(self, clock) -> None:
        """Run the servos' motion on ``clock`` (a graph's simulated time), from the next connect."""
        self._clock = clock

    def connect(self) -> None:
        from aes_planner.drivers.emulator import ServoEmulator

        with self._lock:
            if self.connected:
                return
            link = self._link
            if link is None:
                self._link_dir = tempfile.mkdtemp(prefix="aes-planner-servos-")
                link = str(Path(self._link_dir) / "ttyDXL")
            try:
                clock = {} if self._clock is None else {"clock": self._clock}
                self.emulator = ServoEmulator(self.config.models, baud=self.config.baud, link=link, **clock).start()
                self.config = dataclasses.replace(self.config, port=self.emulator.port)
                super().connect()
            except BaseException:
                self._stop_emulator()
                raise

    def disconnect(self) -> None:
        with self._lock:
            try:
                super().disconnect()
            finally:
                self._stop_emulator()

    # ------------------------------------------------------------------------------ faults
    def inject_hardware_error(self, joint: str, fault: str = "overload") -> None:
        """Raise a hardware alert on ``joint``'s servo (``"overload"``, ``"overheating"``, ...)."""
        emu = self._running()
        if fault not in HARDWARE_ERROR_BITS.values():
            raise ValueError(f"unknown hardware fault {fault!r}; one of {sorted(HARDWARE_ERROR_BITS.values())}")
        emu.inject_hardware_error(self._servo_id(joint), fault)

    def inject_comm_faults(
        self, lost: int = 0, corrupt: int = 0, delayed: int = 0, delay_s: float | None = None
    ) -> None:
        """The next ``lost`` replies are dropped, ``corrupt`` ones get a broken CRC, ``delayed``
        ones come ``delay_s`` late (added to what is already queued)."""
        emu = self._running()
        for name, n in (("lost", lost), ("corrupt", corrupt), ("delayed", delayed)):
            if not (isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= 10_000):
                raise ValueError(f"{name} must be a count 0..10000, got {n!r}")
        if delay_s is not None and not (math.isfinite(delay_s) and 0 <= delay_s <= 10.0):
            raise ValueError(f"delay_s must be within [0, 10] s, got {delay_s!r}")
        with emu.lock:
            emu.faults.drop_next += lost
            emu.faults.corrupt_next += corrupt
            emu.faults.delay_next += delayed
            if delay_s is not None:
                emu.faults.delay_s = float(delay_s)

    def inject_stall(self, joint: str, stalled: bool = True) -> None:
        """``joint``'s servo stops moving toward its goal (an obstruction) until un-stalled."""
        self._running().inject_stall(self._servo_id(joint), stalled)

    def vanish_port(self) -> None:
        """Unplug the emulated adapter: the driver sees I/O errors, then a missing port."""
        self._running().vanish()

    def restore_port(self) -> None:
        """Plug it back in (same servos, same state); the driver reconnects on its next call."""
        self._running().restore()

    def clear_faults(self) -> None:
        """No more injected bus faults, stalls or missing port; hardware errors stay latched in the
        servos until :meth:`reboot`, as on real ones."""
        emu = self._running()
        with emu.lock:
            f = emu.faults
            f.drop_next = f.corrupt_next = f.truncate_next = f.delay_next = 0
            f.drop_rate = f.corrupt_rate = 0.0
            for dxl_id in emu.servos:
                emu.inject_stall(dxl_id, False)
        if emu.pty_path is None:
            emu.restore()

    def _running(self):
        if self.emulator is None:
            raise RuntimeError("the emulator runs only while the gimbal is connected; call connect() first")
        return self.emulator

    def _servo_id(self, joint: str) -> int:
        if joint not in JOINTS:
            raise ValueError(f"joint must be one of {JOINTS}, got {joint!r}")
        return self.config.joint_id(joint)

    def _stop_emulator(self) -> None:
        if self.emulator is not None:
            self.emulator.stop()
            self.emulator = None
        if self._link_dir is not None:
            shutil.rmtree(self._link_dir, ignore_errors=True)
            self._link_dir = None
