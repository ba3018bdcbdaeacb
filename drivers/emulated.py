"""``EmulatedPanTilt``: the Dynamixel driver on a built-in servo emulator (``emulated_pan_tilt``).

The gimbal of the simulated closed loop: the real :class:`~aes_planner.drivers.dynamixel.DynamixelPanTilt`
code path (dynamixel-sdk, Protocol 2.0 on a pty) against a
:class:`~aes_planner.drivers.emulator.ServoEmulator` it starts on ``connect()``.
"""

from __future__ import annotations

import dataclasses

from aes_planner.drivers.dynamixel import DynamixelPanTilt
from aes_planner.drivers.dynamixel_config import EmulatedPanTiltConfig

__all__ = ["EmulatedPanTilt", "EmulatedPanTiltConfig"]


class EmulatedPanTilt(DynamixelPanTilt):
    """:class:`DynamixelPanTilt` on a :class:`~aes_planner.drivers.emulator.ServoEmulator` that it
    starts on ``connect()`` and stops on ``disconnect()``: the gimbal of the simulated closed loop.
    ``emulator`` is the running emulator (None while disconnected), for fault injection."""

    config_class = EmulatedPanTiltConfig

    def __init__(self, config: EmulatedPanTiltConfig):
        super().__init__(config)
        self._link = config.port or None
        self.emulator = None

    def connect(self) -> None:
        from aes_planner.drivers.emulator import ServoEmulator

        with self._lock:
            if self.connected:
                return
            self.emulator = ServoEmulator(self.config.models, baud=self.config.baud, link=self._link).start()
            self.config = dataclasses.replace(self.config, port=self.emulator.port)
            try:
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

    def _stop_emulator(self) -> None:
        if self.emulator is not None:
            self.emulator.stop()
            self.emulator = None
