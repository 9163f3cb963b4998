"""sim_fakes/fake_fanuc.py: the WC_HBEAT watchdog program counts the controller's running time, not its own stalls.

No sockets here: the controller's motion tick (``_advance``) and register writes are driven by hand, as the fake's
event loop does; tests/drivers/test_fanuc_watchdog.py runs the whole fake against the real driver.
"""

from __future__ import annotations

import time

from sim_fakes.fake_fanuc import FakeFanucController
from sim_fakes.fanuc_program import HeartbeatProgram


def test_a_stall_of_the_fakes_own_process_is_not_the_hosts_silence() -> None:
    # The host writes R[90] every 50 ms; the fake's process is not scheduled for 0.35 s and its first tick after
    # that runs before the writes queued meanwhile are read: no trip. Once the host is silent the program trips
    # after 0.3 s of the controller's ticks (arc output off, STOP.G alarm, the register back to 0).
    fake = FakeFanucController(heartbeat=HeartbeatProgram(90, 0.3, (1,)))
    fake._dout[1] = True
    beat = 0
    for tick in range(80):  # 0.32 s of 4 ms ticks, a write every 12th
        fake._advance(0.004)
        if tick % 12 == 11:
            beat += 1
            fake._registers[90] = float(beat)
    time.sleep(0.35)  # the fake's process stands still
    fake._advance(0.35)  # its late tick (the controller counts at most 50 ms of it) ...
    beat += 1
    fake._registers[90] = float(beat)  # ... and only then the host's write of that while
    fake._advance(0.004)
    assert fake._dout[1] and not [e for e in fake._events if e["kind"] == "heartbeat_lost"]
    for _ in range(74):  # the host goes silent: 0.296 s of ticks
        fake._advance(0.004)
    assert fake._dout[1]
    for _ in range(2):
        fake._advance(0.004)
    (lost,) = [e for e in fake._events if e["kind"] == "heartbeat_lost"]
    assert not fake._dout[1] and fake._registers[90] == 0.0
    assert 0.3 <= lost["silent_s"] <= 0.305
