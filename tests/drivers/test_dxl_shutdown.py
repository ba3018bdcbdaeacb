"""Safety on the way out: signals stop the servos with torque off; the emulator's ``--link`` never
touches what is not its own."""

import os
import select
import signal
import subprocess
import sys
import time

import pytest

from aes_planner.cli import main
from aes_planner.drivers.emulator import LinkError, ServoEmulator
from aes_planner.graph.signals import SignalShutdown, stop_on_signals
from tests.helpers import wait_for


# ------------------------------------------------------------------------------ stop_on_signals
@pytest.fixture
def own_handlers():
    """After a signal stop the block leaves SIGINT/SIGTERM ignored (the process is exiting): put
    pytest's handlers back."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield saved
    for s, h in saved.items():
        signal.signal(s, h)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_interrupt_raises_signal_shutdown_at_the_first_signal(sig, own_handlers):
    with pytest.raises(SignalShutdown) as info:
        with stop_on_signals(interrupt=True) as stop:
            os.kill(os.getpid(), sig)
            time.sleep(5.0)  # interrupted
    assert info.value.signum == sig and info.value.exit_code == 128 + sig
    assert isinstance(info.value, KeyboardInterrupt)  # every Ctrl-C clean-up path applies
    assert stop.signum == sig and stop.exit_code == 128 + sig and stop.is_set()
    assert signal.getsignal(sig) is signal.SIG_IGN  # the process is on its way out: no more signals


def test_without_a_signal_the_previous_handlers_are_restored():
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with stop_on_signals() as stop:
        assert signal.getsignal(signal.SIGTERM) is not before[signal.SIGTERM]
    assert stop.exit_code is None and not stop.is_set()
    assert {s: signal.getsignal(s) for s in before} == before


def test_further_signals_do_not_interrupt_the_cleanup(own_handlers):
    cleaned = []
    with pytest.raises(SignalShutdown) as info:
        with stop_on_signals(interrupt=True) as stop:
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5.0)
            finally:
                os.kill(os.getpid(), signal.SIGTERM)  # a supervisor repeats itself mid-cleanup
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                cleaned.append(True)
    assert cleaned == [True]
    assert info.value.signum == signal.SIGTERM and stop.count == 3  # the first one decides; all counted


def test_a_loop_stops_on_the_first_signal_and_nothing_is_ever_raised(own_handlers):
    with stop_on_signals() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.wait(5.0)  # the loop's stop flag, nothing raised
        for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGTERM):
            os.kill(os.getpid(), sig)  # an impatient user: counted, logged, not raised
        time.sleep(0.05)
    assert stop.signum == signal.SIGINT and stop.exit_code == 130 and stop.count == 4


def test_the_first_signal_is_the_first_to_arrive_not_the_lowest_numbered(own_handlers):
    """SIGTERM, then SIGINT, both arriving while the main thread is in C (here a join; in a launch,
    a driver's read): Python runs their handlers in signal-number order, SIGINT's first. The stop
    names SIGTERM, the one that came first (a supervisor's SIGTERM, then a user's Ctrl-C: 143)."""
    import threading

    go = threading.Event()

    def send():
        go.wait()
        # to this thread, not the process: the kernel may hand a process's signal to any thread
        # that does not block it (Zenoh's, other tests' leftovers), whose handler then runs late
        # and, with both pending at once, lowest-numbered first
        me = threading.get_ident()
        signal.pthread_kill(me, signal.SIGTERM)
        signal.pthread_kill(me, signal.SIGINT)

    sender = threading.Thread(target=send)  # started before the main thread blocks them: it takes both
    sender.start()
    with stop_on_signals() as stop:
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            go.set()
            sender.join()  # both signals' C handlers ran on the sender's thread, in the order sent
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        # polled: Python runs the handlers in the main thread between bytecodes, and a blocking
        # wait is not interrupted by a signal another thread's C handler took
        assert wait_for(lambda: stop.count == 2)
    assert stop.signum == signal.SIGTERM and stop.exit_code == 143


# ------------------------------------------------------------------------------ gimbal move + SIGTERM
@pytest.mark.parametrize(
    ("sig", "times"), [(signal.SIGTERM, 1), (signal.SIGINT, 1), (signal.SIGTERM, 2), (signal.SIGINT, 2)]
)
def test_a_signal_during_gimbal_move_stops_with_torque_off(tmp_path, sig, times):
    cfg = tmp_path / "slow.yaml"
    cfg.write_text(
        "profile_velocity_deg_s: 10.0\nprofile_acceleration_deg_s2: 100.0\nlatency_timer_ms: 100\nretries: 5\n"
    )
    with ServoEmulator() as emu:
        proc = subprocess.Popen(
            [sys.executable, "-m", "aes_planner", "gimbal", "move", "--port", emu.port, "--config", str(cfg)]
            + ["--pan-deg", "90", "--tilt-deg", "0"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            ready, _, _ = select.select([proc.stdout], [], [], 60.0)
            assert ready, "gimbal move printed nothing"
            assert proc.stdout.readline().startswith("moving to pan +90.00 deg")
            time.sleep(0.3)  # well on the way (90 deg at 10 deg/s takes 9 s)
            with emu.lock:
                assert [s.torque_on for _, s in sorted(emu.servos.items())] == [True, True]
            proc.send_signal(sig)
            if times == 2:  # an impatient second one: waits for the torque-off, changes nothing
                time.sleep(0.1)
                proc.send_signal(sig)
            rc = proc.wait(20.0)
            err = proc.stderr.read()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(5.0)
            proc.stdout.close()
            proc.stderr.close()
        assert rc == 128 + sig, err
        assert f"stopped by {signal.Signals(sig).name}: stopped, torque off" in err and "Traceback" not in err
        with emu.lock:
            servos = [s for _, s in sorted(emu.servos.items())]
            assert [s.torque_on for s in servos] == [False, False]
            pan = servos[0]
            pan.update()
            stopped_at = pan.get("present_position")
            assert pan.velocity_ticks_s == 0.0 and pan.get("moving") == 0
            assert 2048 < stopped_at < 2048 + 1024  # stopped on the way, short of +90 deg
        time.sleep(0.1)
        with emu.lock:
            pan.update()
            assert pan.get("present_position") == stopped_at  # and stays there


# ------------------------------------------------------------------------------ --link
def test_link_refuses_an_existing_file_and_leaves_it_alone(tmp_path, capsys):
    victim = tmp_path / "notes.txt"
    victim.write_text("precious")
    with pytest.raises(LinkError, match="a file exists there"):
        ServoEmulator(link=victim)
    assert main(["gimbal", "emulate", "--link", str(victim)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "a file exists there" in err and err.count("\n") == 1
    assert victim.read_text() == "precious" and not victim.is_symlink()


def test_link_refuses_a_folder_and_a_live_symlink(tmp_path):
    folder = tmp_path / "d"
    folder.mkdir()
    with pytest.raises(LinkError, match="a folder exists there"):
        ServoEmulator(link=folder)
    assert folder.is_dir()
    target = tmp_path / "device"
    target.write_text("x")
    live = tmp_path / "by-id"
    live.symlink_to(target)
    with pytest.raises(LinkError, match="which exists"):
        ServoEmulator(link=live)
    assert os.readlink(live) == str(target)
    with pytest.raises(LinkError, match="does not exist"):
        ServoEmulator(link=tmp_path / "missing" / "tty")


def test_link_replaces_a_dangling_symlink_and_removes_only_its_own(tmp_path):
    link = tmp_path / "ttyDXL"
    link.symlink_to(tmp_path / "gone")  # what a killed emulator leaves behind
    beside = tmp_path / "ttyDXL.tmp"
    beside.write_text("not ours")  # the old code deleted this
    with ServoEmulator(link=link) as emu:
        assert os.readlink(link) == emu.pty_path
    assert not os.path.lexists(link)
    assert beside.read_text() == "not ours"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ttyDXL.tmp"]  # no temporary left over

    # the link was re-pointed by someone else meanwhile: it is theirs now, left alone
    with ServoEmulator(link=link):
        link.unlink()
        link.symlink_to(beside)
    assert os.readlink(link) == str(beside) and beside.read_text() == "not ours"
