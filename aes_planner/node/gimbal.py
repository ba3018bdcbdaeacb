"""``GimbalNode``: any :class:`~aes_planner.devices.Gimbal` on the bus.

It publishes ``gimbal/state`` at ``rate_hz`` and executes ``gimbal/command``:

* ``move``: checked against the launch's joint limits when it sets some (the platform's): a move
  beyond them, or not finite, is refused and counted (nothing reaches the servos); the device
  applies the one clamp to its own limits (the clamp rule: :class:`~aes_planner.geometry.rig.JointLimits`);
* ``stop``: hold where the joints are now;
* ``reboot``: clear a latched hardware error (the only way out of ``fault``).

On a hardware error the node stops commanding (moves are refused and counted), reports
``status: fault`` with the faults in every state message, and resumes only after a reboot
request. Communication errors are counted and reported (``status: comm_error``, ``port_lost``
while the serial port is gone); the driver reopens a port that comes back, takes control again
and holds its last goal (its ``port_losses`` and ``reconnects`` are in the diagnostics). :meth:`GimbalNode.stop` disconnects the device, which leaves
the motors unpowered.

On a simulated clock (``clock: sim``, :mod:`aes_planner.graph.clock`) the device takes its time
from the node's ``now``: the servo emulator in its own process reads it from a shared
:class:`~aes_planner.drivers.emulator.FileClock` the node sets at each step, an in-process
emulated or simulated gimbal from the same clock, and states are stamped ``now``; a step that
sent a command reads the device back before it ends, so that the command takes effect at ``now``
(a move is a write the servos do not answer; see :meth:`GimbalNode._settle_commands`); and the
last try of every serial exchange waits up to :data:`SIM_LINK_PATIENCE_S` for its reply, so that
a loaded machine's late replies fail no exchange (which would change the run). A real gimbal
cannot run on it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from aes_planner.config import require, require_numbers, short_repr
from aes_planner.devices import (
    DeviceError,
    Gimbal,
    GimbalCommError,
    GimbalHardwareError,
    GimbalPortLostError,
    joint_command,
    make_device,
)
from aes_planner.geometry.rig import JointCommandError, JointLimits
from aes_planner.graph.base import LaunchContext, Node, Outputs
from aes_planner.messages import Diagnostics, GimbalCommand, GimbalState
from aes_planner.node.scene import launch_scene

log = logging.getLogger(__name__)

#: On a simulated clock, how long the last try of a serial exchange waits for the emulator's reply
#: (wall seconds; :meth:`~aes_planner.drivers.dynamixel.DynamixelPanTilt.set_patience`): a reply
#: that a loaded machine delays must not fail the exchange, which would change the run.
SIM_LINK_PATIENCE_S = 10.0
#: How long connecting waits for a servo emulator the node started to answer the driver's first
#: ping (wall seconds): a fresh process on a loaded machine may take a while to get the CPU.
EMULATOR_ANSWER_TIMEOUT_S = 30.0

#: No limits of the launch's own: only the finiteness check (the device clamps to its own).
_UNLIMITED = JointLimits((-math.inf, math.inf), (-math.inf, math.inf))

__all__ = ["GimbalNode", "GimbalNodeConfig"]


#: ``aes-planner gimbal emulate`` options a launch may pass (the servos and baud come from the device).
EMULATOR_OPTIONS = ("--link", "--drop-rate", "--corrupt-rate", "--seed")


def _check_emulator_args(args: list[str]) -> None:
    """``emulator_args`` are OPTION VALUE pairs among :data:`EMULATOR_OPTIONS` (the emulator
    checks the values and says what is wrong with them)."""
    for i in range(0, len(args), 2):
        require(
            args[i] in EMULATOR_OPTIONS and i + 1 < len(args) and not args[i + 1].startswith("--"),
            f"emulator_args[{i}]",
            f"expected OPTION VALUE pairs with OPTION one of {', '.join(EMULATOR_OPTIONS)}, got {short_repr(args[i : i + 2])}",
        )


@dataclass
class GimbalNodeConfig:
    """* ``device``: the gimbal as a launch-file device mapping (``type:`` word + its settings).
    * ``rate_hz``: ``gimbal/state`` rate.
    * ``pan_limits_deg``, ``tilt_limits_deg``: extra joint limits (the platform's; a sim launch
      takes them from the scene's rig): a move beyond them is refused and counted, not clamped;
      the device clamps to its own limits.
    * ``diagnostics_period_s``: how often ``gimbal/diagnostics`` is published.
    * ``emulate``: start the Protocol 2.0 servo emulator in a child process (its own GIL, like
      real servos) and connect the ``dynamixel_pan_tilt`` device to its pty (the device's
      ``port`` is replaced); ``emulator_args`` are extra ``aes-planner gimbal emulate`` options.
    """

    device: dict[str, Any] = field(default_factory=lambda: {"type": "emulated_pan_tilt"})
    rate_hz: float = 20.0
    pan_limits_deg: tuple[float, float] | None = None
    tilt_limits_deg: tuple[float, float] | None = None
    diagnostics_period_s: float = 1.0
    emulate: bool = False
    emulator_args: list[str] = field(default_factory=list)

    def __post_init__(self):
        require_numbers(self, ("rate_hz", "diagnostics_period_s"))
        require(
            self.diagnostics_period_s <= 3600,
            "diagnostics_period_s",
            f"must be <= 3600 s, got {self.diagnostics_period_s}",
        )
        require(
            not self.emulate or self.device.get("type") == "dynamixel_pan_tilt",
            "emulate",
            f"the emulator speaks to the dynamixel_pan_tilt driver; device.type is {self.device.get('type')!r}",
        )
        _check_emulator_args(self.emulator_args)
        require(0.01 <= self.rate_hz <= 1000, "rate_hz", f"must be in [0.01, 1000] Hz, got {self.rate_hz}")
        for name in ("pan_limits_deg", "tilt_limits_deg"):
            lim = getattr(self, name)
            require(lim is None or lim[0] < lim[1], name, f"min must be below max, got {lim}")


class GimbalNode(Node):
    """See the module docstring. ``device`` replaces the configured one (tests)."""

    config_class = GimbalNodeConfig
    inputs = {"gimbal/command": (GimbalCommand, 16)}
    outputs = {"gimbal/state": (GimbalState, False), "gimbal/diagnostics": (Diagnostics, False)}

    def __init__(
        self,
        config: GimbalNodeConfig | None = None,
        node_id: str = "gimbal",
        context: LaunchContext | None = None,
        device: Gimbal | None = None,
    ):
        config = config or GimbalNodeConfig()
        super().__init__(config, node_id, context)
        spec = dict(config.device)
        if config.emulate:
            spec["port"] = "<emulator>"  # replaced by the emulator's pty on start()
        self.device: Gimbal = device if device is not None else make_device(spec, "device", kind=Gimbal)
        self.emulator = None
        self.limits_rad = self._limits(context)
        self.status = "idle"
        self.faults: tuple[str, ...] = ()
        self.counters = dict.fromkeys(
            (
                "commands_in",
                "moves",
                "moves_resent",
                "commands_refused",
                "comm_errors",
                "hardware_errors",
                "reboots",
                "states",
                "emulator_restarts",
            ),
            0,
        )
        self._pending_move: tuple[float, float] | None = None  # checked joints the device has yet to take
        self._seq = 0  # gimbal/state's counter
        self._diag_seq = 0  # gimbal/diagnostics' own
        self._last_state_s = -math.inf
        self._last_diag_s = -math.inf
        self.last_state: GimbalState | None = None
        self.sim_clock = None  # a FileClock the device reads its time from (simulated clock)

    #: device types whose time a simulated clock can drive (``dynamixel_pan_tilt`` only emulated)
    SIM_DEVICES = ("emulated_pan_tilt", "sim_pan_tilt")

    @classmethod
    def sim_clock_problem(cls, config: GimbalNodeConfig) -> str | None:
        kind = config.device.get("type")
        if config.emulate or kind in cls.SIM_DEVICES:
            return None
        return f"drives a real gimbal (device type {kind!r}; emulate: false), which moves in real time"

    def _limits(self, context: LaunchContext | None):
        c = self.config
        pan, tilt = c.pan_limits_deg, c.tilt_limits_deg
        if (pan is None or tilt is None) and context is not None and context.scene is not None:
            scene = launch_scene(context)
            if scene.rig is not None:
                pan = pan or scene.rig.pan_tilt.pan_limits_deg
                tilt = tilt or scene.rig.pan_tilt.tilt_limits_deg
        if pan is None and tilt is None:
            return None
        pan = pan or (-180.0, 180.0)
        tilt = tilt or (-90.0, 90.0)
        return tuple(math.radians(a) for a in pan), tuple(math.radians(a) for a in tilt)

    @property
    def period_s(self) -> float:
        return 1.0 / self.config.rate_hz

    def start(self) -> None:
        clock_args: list[str] = []
        if self.context.clock == "sim":
            from aes_planner.drivers.emulator import FileClock

            problem = self.sim_clock_problem(self.config)
            if problem is None and not self.config.emulate and not hasattr(self.device, "use_clock"):
                problem = f"has a device ({type(self.device).__name__}) that keeps its own time"
            if problem:
                from aes_planner.graph.base import NodeError

                raise NodeError(f"{self.node_id} {problem}: it cannot run on a simulated clock; use --clock wall")
            self.sim_clock = FileClock.create()
            if self.config.emulate:
                clock_args = ["--clock-file", str(self.sim_clock.path)]
            else:
                self.device.use_clock(self.sim_clock)
        if self.config.emulate:
            self._emulator_args = [*self.config.emulator_args, *clock_args]
            self._start_emulator()
        try:
            self._connect()
        except BaseException:
            self.stop()
            raise
        self.status = "ok"

    def _connect(self) -> None:
        """Connect the device. An emulator's servos (in a process or a thread the node started)
        get :data:`EMULATOR_ANSWER_TIMEOUT_S` to answer the first ping, however loaded the machine;
        on a simulated clock every later exchange's last try waits up to :data:`SIM_LINK_PATIENCE_S`
        for its reply (the link's delays are the machine's, not the simulated world's)."""
        dev = self.device
        patient = hasattr(dev, "set_patience")
        emulated = self.config.emulate or self.config.device.get("type") in self.SIM_DEVICES
        if patient and emulated:
            dev.set_patience(EMULATOR_ANSWER_TIMEOUT_S)
        try:
            dev.connect()
        except GimbalCommError as exc:
            if not self.config.emulate or self.emulator is None:
                raise
            proc = self.emulator.proc
            code = proc.poll()
            how = (
                f"exited with status {code}"
                if code is not None
                else f"is running (pid {proc.pid}) but did not answer within {EMULATOR_ANSWER_TIMEOUT_S:g} s"
            )
            raise GimbalCommError(
                f"{self.node_id}: the servo emulator on {self.emulator.port} {how} to the driver's first ping; "
                f"is the machine overloaded, or the emulator's options wrong ({' '.join(self._emulator_args) or 'none'})? "
                f"The driver said: {exc}"
            ) from exc
        finally:
            if patient:
                dev.set_patience(SIM_LINK_PATIENCE_S if self.sim_clock is not None else 0.0)

    def _start_emulator(self) -> None:
        """Start the servo emulator's process and point the driver at the pty it opened."""
        import dataclasses

        from aes_planner.drivers.emulator import EmulatorProcess

        dev = self.device
        self.emulator = EmulatorProcess(
            tuple(getattr(dev.config, "models", ("xm430-w350", "xm430-w350"))),
            baud=dev.config.baud,
            args=self._emulator_args,
        ).__enter__()
        dev.config = dataclasses.replace(dev.config, port=self.emulator.port)

    def _replace_dead_emulator(self) -> None:
        """The emulator's process ended while the node runs (killed, crashed): start another.

        Its pty's number is free for the next pty any process opens (another node's emulator), so
        the driver must not reopen that path as it would a real adapter's: it would drive someone
        else's servos. The new emulator's servos start where a powered-up rig's do, torque off; the
        driver takes control again on connecting, and a move the node still holds is sent again."""
        if self.emulator is not None:  # else the last try to start one failed
            code = self.emulator.stop()
            self.emulator = None
            self.counters["emulator_restarts"] += 1
            log.error("%s: the servo emulator exited (status %s); starting another", self.node_id, code)
        try:
            self.device.disconnect()
        except DeviceError as exc:
            log.warning("%s: closing the dead emulator's port: %s", self.node_id, exc)
        try:
            self._start_emulator()
            self.device.connect()
        except DeviceError as exc:
            self.counters["comm_errors"] += 1
            self.status = "port_lost"
            log.error("%s: the new servo emulator did not come up (%s); trying again next step", self.node_id, exc)
            if self.emulator is not None:
                self.emulator.stop()
                self.emulator = None
            return
        self.status = "ok"

    def stop(self) -> None:
        try:
            self.device.disconnect()
        finally:
            self.status = "stopped"
            if self.emulator is not None:
                self.emulator.stop()
                self.emulator = None
            if self.sim_clock is not None:
                self.sim_clock.close()
                self.sim_clock = None

    # ----------------------------------------------------------------------------------- step
    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        out: Outputs = {"gimbal/state": [], "gimbal/diagnostics": []}
        if self.sim_clock is not None:
            self.sim_clock.set(now)  # before any exchange: the servos move to this time
        if self.config.emulate and (self.emulator is None or self.emulator.proc.poll() is not None):
            self._replace_dead_emulator()
        commands = inputs.get("gimbal/command", ())
        for cmd in commands:
            self.counters["commands_in"] += 1
            self._execute(cmd)
        sent = bool(commands)
        if self._pending_move is not None and not commands:
            self._resend_pending()
            sent = True
        if sent and self.sim_clock is not None:
            self._settle_commands()
        if now - self._last_state_s >= self.period_s * 0.999:
            self._last_state_s = now
            state = self._read_state()
            if state is not None:
                if self.sim_clock is not None:
                    state.stamp_s = now  # read at ``now`` on the graph's clock, not the machine's
                out["gimbal/state"].append(state)
        if now - self._last_diag_s >= self.config.diagnostics_period_s:
            self._last_diag_s = now
            self._diag_seq += 1
            out["gimbal/diagnostics"].append(
                Diagnostics(now, self.node_id, self.status, self._counters(), {}, self._diag_seq)
            )
        return out

    def _counters(self) -> dict[str, int]:
        """The node's counters, plus the driver's own where it keeps them: servos found with torque
        off behind its back, serial ports lost and reopened."""
        out = dict(self.counters)
        for name in ("torque_losses", "port_losses", "reconnects"):
            value = getattr(self.device, name, None)
            if isinstance(value, int):
                out[name] = value
        return out

    def check(self, pan_rad: float, tilt_rad: float, launch_limits: bool = True) -> tuple[float, float]:
        """The joints unchanged when they are two finite numbers inside the launch's limits (when
        it sets some and ``launch_limits``; :meth:`JointLimits.check`), else
        :class:`JointCommandError`. The node never clamps: the device does, to its own limits."""
        pan_rad, tilt_rad = joint_command(pan_rad, tilt_rad)
        limits = JointLimits(*self.limits_rad) if self.limits_rad is not None and launch_limits else _UNLIMITED
        return limits.check(pan_rad, tilt_rad)

    def _execute(self, cmd) -> None:
        kind = getattr(cmd, "kind", None)
        self._pending_move = None  # a newer command supersedes a move the device has not taken yet
        try:
            if kind == "reboot":
                self.device.reboot()
                self.counters["reboots"] += 1
                self.faults = ()
                self.status = "ok"
                log.warning("%s: rebooted; accepting commands again", self.node_id)
            elif self.status == "fault":
                self.counters["commands_refused"] += 1
                log.warning(
                    "%s: %s refused: hardware fault (%s); send a reboot request",
                    self.node_id,
                    kind,
                    ", ".join(self.faults),
                )
            elif kind == "move":
                pan, tilt = self.check(cmd.pan_rad, cmd.tilt_rad)
                self._pending_move = (pan, tilt)  # until the device took it (kept over a lost port)
                self.device.move_to(pan, tilt)
                self._moved()
            elif kind == "stop":
                s = self.device.state()
                self.device.move_to(*self.check(*_joints(s), launch_limits=False))  # hold: where it is
            else:
                self.counters["commands_refused"] += 1
        except JointCommandError as exc:
            self.counters["commands_refused"] += 1
            log.warning("%s: command refused: %s", self.node_id, exc)
        except GimbalHardwareError as exc:
            self._on_fault(tuple(f"{j}: {f}" for j, fs in exc.faults.items() for f in fs) or (str(exc),))
        except GimbalCommError as exc:
            self.counters["comm_errors"] += 1
            self.status = _comm_status(exc) if self.status != "fault" else self.status
            kept = "; the move is kept and sent when the gimbal answers again" if self._pending_move else ""
            log.warning("%s: %s%s", self.node_id, exc, kept)
        except DeviceError as exc:
            self.counters["comm_errors"] += 1
            self._pending_move = None
            log.warning("%s: %s", self.node_id, exc)

    def _settle_commands(self) -> None:
        """On a simulated clock, hold the step until the device has taken what this step sent.

        A Dynamixel move is a sync write, which the servos do not answer: the emulator (a thread,
        or a process of its own) applies it whenever it next gets the CPU, and by then the graph's
        clock may have moved on, so the move began at ``now`` or a gimbal period later depending
        on the machine's load (two ``make demo`` runs took the same captures 0.08 s apart). A
        state read is answered only after everything sent before it has been handled: one read
        here (not published) makes the move begin at ``now`` on every run. A read that fails is
        counted as a communication error (the move may then begin late, as on a real bus)."""
        try:
            self.device.state()
        except GimbalHardwareError:
            pass  # the state read reports it, as for any fault
        except DeviceError as exc:
            self.counters["comm_errors"] += 1
            log.debug("%s: reading back after a command failed: %s", self.node_id, exc)

    def _moved(self) -> None:
        self._pending_move = None
        self.counters["moves"] += 1
        if self.status in _COMM_STATUSES:
            self.status = "ok"

    def _resend_pending(self) -> None:
        """A move that met a communication error (a lost port, a bus that did not answer) is sent
        again at each step until the device takes it or a newer command replaces it: an accepted
        command is not lost. Each resend is counted (``moves_resent``) once it goes through; the
        failures are the state reads' ``comm_errors`` already."""
        if self.status == "fault":
            self._pending_move = None
            return
        try:
            self.device.move_to(*self._pending_move)
        except GimbalHardwareError as exc:
            self._pending_move = None
            self._on_fault(tuple(f"{j}: {f}" for j, fs in exc.faults.items() for f in fs) or (str(exc),))
        except GimbalCommError as exc:
            log.debug("%s: resending the move failed: %s", self.node_id, exc)
        except DeviceError as exc:
            self._pending_move = None
            self.counters["comm_errors"] += 1
            log.warning("%s: dropped the kept move: %s", self.node_id, exc)
        else:
            self.counters["moves_resent"] += 1
            self._moved()

    def _on_fault(self, faults: tuple[str, ...]) -> None:
        if self.status != "fault":
            self.counters["hardware_errors"] += 1
            log.error("%s: hardware error %s: stopped; resumes after a reboot request", self.node_id, ", ".join(faults))
        self.status = "fault"
        self.faults = tuple(faults)[:16]

    def _read_state(self) -> GimbalState | None:
        try:
            s = self.device.state()
        except GimbalHardwareError as exc:
            self._on_fault(tuple(f"{j}: {f}" for j, fs in exc.faults.items() for f in fs) or (str(exc),))
            return None
        except DeviceError as exc:
            self.counters["comm_errors"] += 1
            if self.status != "fault":
                self.status = _comm_status(exc)
            log.debug("%s: state read failed: %s", self.node_id, exc)
            return None
        if s.hardware_error:
            self._on_fault(tuple(s.hardware_error))
        elif self.status in _COMM_STATUSES:
            self.status = "ok"
        self._seq += 1
        self.counters["states"] += 1
        faults = tuple(s.hardware_error) or (self.faults if self.status == "fault" else ())
        try:
            msg = GimbalState.from_device(s, sequence=self._seq, status=self.status)
            if faults != msg.hardware_error:
                msg.hardware_error = faults
        except Exception as exc:  # a device that reports NaN must not publish it
            self.counters["comm_errors"] += 1
            log.warning("%s: unpublishable state %s: %s", self.node_id, s, exc)
            return None
        self.last_state = msg
        return msg


_COMM_STATUSES = ("comm_error", "port_lost")


def _comm_status(exc: BaseException) -> str:
    return "port_lost" if isinstance(exc, GimbalPortLostError) else "comm_error"


def _joints(state) -> tuple[float, float]:
    if hasattr(state, "pan_rad"):
        return state.pan_rad, state.tilt_rad
    return state.yaw_rad, state.pitch_rad
