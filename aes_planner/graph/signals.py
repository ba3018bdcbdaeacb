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
import os
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

    arrivals = _ArrivalOrder()

    def handler(signum, frame):
        stop.count += 1
        if stop.signum is not None:
            name = signal.Signals(signum).name
            log.warning("%s ignored (%d signals so far): finishing the clean-up first (torque off)", name, stop.count)
            return
        stop.signum = arrivals.first(signals) or signum
        stop.set()
        log.info(
            "%s: stopping (servos are left with torque off; further signals wait for that)",
            signal.Signals(stop.signum).name,
        )
        if interrupt:
            raise SignalShutdown(stop.signum)

    previous = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            # after a signal stop the process is on its way out: later signals are ignored (SIG_IGN,
            # which the interpreter keeps through its finalization, unlike a Python handler it
            # resets to the default: a signal there killed the process, status -15, not 143)
            signal.signal(sig, old if stop.signum is None else signal.SIG_IGN)
        arrivals.close()


class _ArrivalOrder:
    """The order signals arrived in. Python runs the handlers of signals that arrived while the
    main thread was in C (a driver's read, a join) in signal-number order, not arrival order:
    SIGTERM then SIGINT 5 ms apart ran SIGINT's handler first, and the process exited 130, not
    143. The interpreter's C-level handler writes each signal's number, as it arrives, to the
    wakeup fd (:func:`signal.set_wakeup_fd`): the first byte there is the first signal. Left out
    when something else (an asyncio loop) holds the wakeup fd: then the first handler run counts."""

    def __init__(self) -> None:
        self.fds: tuple[int, int] | None = None
        self.previous = -1
        read_fd, write_fd = os.pipe()
        os.set_blocking(read_fd, False)
        os.set_blocking(write_fd, False)
        try:
            self.previous = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        except ValueError:  # not the main thread
            self.previous = -1
            os.close(read_fd)
            os.close(write_fd)
            return
        if self.previous != -1:  # someone else's: give it back
            signal.set_wakeup_fd(self.previous)
            os.close(read_fd)
            os.close(write_fd)
            return
        self.fds = (read_fd, write_fd)

    def first(self, signals: tuple[int, ...]) -> int | None:
        """The first of ``signals`` that arrived (and drains the record), or None when unknown."""
        if self.fds is None:
            return None
        try:
            arrived = os.read(self.fds[0], 512)
        except (BlockingIOError, OSError):
            return None
        return next((int(b) for b in arrived if b in signals), None)

    def close(self) -> None:
        if self.fds is None:
            return
        with contextlib.suppress(ValueError):
            signal.set_wakeup_fd(-1)
        for fd in self.fds:
            os.close(fd)
        self.fds = None
