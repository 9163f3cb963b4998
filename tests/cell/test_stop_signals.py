"""cell.commands.stop_signals: signals ignored while devices start, the first one recorded once armed, the previous
handlers back afterwards. The signals are sent to this very process (main thread, where Python runs handlers)."""

from __future__ import annotations

import os
import signal
import threading
import time

from cell.commands.stop_signals import SIGNALS, StopSignals


def test_before_arming_a_signal_is_ignored_and_after_it_the_first_one_is_the_answer() -> None:
    before = {sig: signal.getsignal(sig) for sig in SIGNALS}
    with StopSignals() as stops:
        assert all(signal.getsignal(sig) is signal.SIG_IGN for sig in SIGNALS)
        os.kill(os.getpid(), signal.SIGTERM)  # ignored: the test process lives on
        stops.arm()
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)  # a second one does not change the answer
        assert stops.wait() == "SIGTERM"
    assert {sig: signal.getsignal(sig) for sig in SIGNALS} == before


def test_wait_blocks_until_a_signal_arrives() -> None:
    with StopSignals() as stops:
        stops.arm()
        timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
        try:
            assert stops.wait() == "SIGINT"
        finally:
            timer.cancel()


def _ignore_sigterm_and_sleep() -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    time.sleep(60)


def test_child_processes_still_running_at_exit_are_ended_within_the_bound() -> None:
    # multiprocessing's own exit handler terminates such a child and then waits for it without a bound
    import multiprocessing

    from cell.commands.stop_signals import end_child_processes

    ctx = multiprocessing.get_context("spawn")
    child = ctx.Process(target=_ignore_sigterm_and_sleep, name="stubborn", daemon=True)
    child.start()
    time.sleep(1.0)  # it has set its handler
    t0 = time.monotonic()
    assert end_child_processes(timeout_s=0.5) == ["stubborn"]
    assert not child.is_alive() and child.exitcode == -signal.SIGKILL
    assert time.monotonic() - t0 < 2.0
    assert end_child_processes(timeout_s=0.5) == []
