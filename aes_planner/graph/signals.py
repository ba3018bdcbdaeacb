"""Stopping on SIGINT/SIGTERM with a clean-up no later signal can interrupt.

Every entry point that drives servos (``aes-planner launch`` in one process or one per node,
``demo``, each supervised node process, the ``gimbal`` commands) and every long-running bus
command runs under :func:`stop_on_signals`. The contract, whatever signals follow and however
fast:

* **the first** SIGINT or SIGTERM stops the work: it sets the :class:`SignalStop` the block
  yields (a loop polls it and returns), or, with ``interrupt=True`` (a straight-line command
  blocked in a device call), raises :class:`SignalShutdown` in the main thread, so the ``with
  gimbal:`` blocks on the way out turn torque off;
* **every later** signal is counted and logged, never raised: the clean-up (a gimbal's
  torque-off, the supervisor stopping its children in reverse order, a Zenoh session closing its
  threads) always runs to its end, bounded by the drivers' timeouts. SIGKILL remains the last
  resort (and leaves torque as it was);
* the process exits with ``128 + the first signal`` (130 for SIGINT, 143 for SIGTERM;
  :attr:`SignalStop.exit_code`), so a script tells a signal stop from success.

After a signal the block leaves SIGINT and SIGTERM ignored when it ends (the process is on its
way out: a signal during the interpreter's exit must not kill it with another status); a block
that saw no signal restores the previous handlers. Signal handlers run only in the main
thread: entered elsewhere, the block installs nothing and yields a stop that only the caller sets.

Example::

    with stop_on_signals() as stop:            # a loop that polls
        try:
            launch.start()
            launch.run(until=stop.is_set)
        finally:
            launch.stop()                       # torque off; a second Ctrl-C cannot cut it short
    return stop.exit_code or 0

    try:                                        # a command blocked in the driver
        with stop_on_signals(interrupt=True), make_device(spec) as gimbal:
            gimbal.move_to(pan_rad, tilt_rad)
            gimbal.wait_until_reached()
    except SignalShutdown as exc:
        return exc.exit_code
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Iterator

__all__ = ["SignalShutdown", "SignalStop", "stop_on_signals"]

log = logging.getLogger(__name__)

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class SignalShutdown(KeyboardInterrupt):
    """Raised in the main thread by ``stop_on_signals(interrupt=True)`` at the first signal.

    A :class:`KeyboardInterrupt` subclass, so every ``with device:`` block, ``finally`` and
    Ctrl-C handler on the way out runs as for Ctrl-C (``except Exception`` does not swallow it).
    ``signum`` is the signal; ``exit_code`` the shell convention ``128 + signum`` (130 for SIGINT,
    143 for SIGTERM).
    """

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.exit_code = 128 + self.signum
        super().__init__(f"stopped by {signal.Signals(self.signum).name}")


class SignalStop(threading.Event):
    """Set at the first signal (or by :meth:`set`): ``signum`` is that first signal (None until
    one arrives), ``count`` how many arrived, ``exit_code`` ``128 + signum`` (None without one)."""

    def __init__(self) -> None:
        super().__init__()
        self.signum: int | None = None
        self.count = 0

    @property
    def exit_code(self) -> int | None:
        return None if self.signum is None else 128 + self.signum

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum is not None else ""


@contextlib.contextmanager
def stop_on_signals(*, interrupt: bool = False, signals: tuple[int, ...] = STOP_SIGNALS) -> Iterator[SignalStop]:
    """See the module docstring: the first signal sets the yielded :class:`SignalStop` (and with
    ``interrupt`` raises :class:`SignalShutdown`); the later ones are counted, logged, ignored."""
    stop = SignalStop()
    if threading.current_thread() is not threading.main_thread():
        log.debug("stop_on_signals outside the main thread: no handler installed (the caller stops the work)")
        yield stop
        return

    def handler(signum, frame):
        stop.count += 1
        name = signal.Signals(signum).name
        if stop.signum is not None:
            log.warning("%s ignored (%d signals so far): finishing the clean-up first (torque off)", name, stop.count)
            return
        stop.signum = signum
        stop.set()
        log.info("%s: stopping (servos are left with torque off; further signals wait for that)", name)
        if interrupt:
            raise SignalShutdown(signum)

    previous = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            # after a signal stop the process is on its way out: later signals are ignored (SIG_IGN,
            # which the interpreter keeps through its finalization, unlike a Python handler it
            # resets to the default: a signal there killed the process, status -15, not 143)
            signal.signal(sig, old if stop.signum is None else signal.SIG_IGN)
