"""How the processes that carry a controller's timing (the drivers' I/O processes, the fakes) start: their stop
signals and their scheduling priority.

Units: nice levels (-20 best .. 19). Linux gives each thread its own nice level and a new thread the level of the
thread that starts it, so the call belongs at the top of a process's entry point.
"""

from __future__ import annotations

import os
import signal

IO_PROCESS_NICE = -10
"""The nice level the drivers' I/O processes ask for (where the OS allows it: root or CAP_SYS_NICE)."""


def raise_own_priority(nice: int = IO_PROCESS_NICE) -> bool:
    """Ask the OS for a better scheduling priority (a lower nice level) for the calling thread and the threads it
    starts afterwards; True when granted. For a process whose timing the cell's safety leans on: the drivers' I/O
    processes send the controller's heartbeat (the UR worker a kick every 50 ms against a 0.3 s watchdog, the
    FANUC one a register write) and read the controller's state; the fakes stand in for controllers that never miss
    a cycle. On a loaded host (a soak beside two test suites on two cores, load 8-10) a process of the default
    priority was not scheduled for 0.3-0.6 s at times and the controller's watchdog stopped a healthy weld.
    Ordinary scheduling, a higher weight only: never a real-time class, which a busy-waiting ur-rtde call could turn
    into a stuck core."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, min(nice, os.getpriority(os.PRIO_PROCESS, 0)))
    except (OSError, AttributeError):  # not permitted (an ordinary user), or no such call on this OS
        return False
    return True


def enter_io_process(nice: int = IO_PROCESS_NICE) -> bool:
    """The first call of such a process's entry point, before any thread starts: Ctrl-C ignored (it reaches the whole
    process group; the parent handles it and stops this process through its handle), SIGTERM back to its default (a
    parent that ignored it while starting this one, as ``weldcell serve`` does, passed that on across exec; its
    terminate(), and multiprocessing's at exit, which then waits for the child without a bound, must end this
    process), and :func:`raise_own_priority`. True when the priority was granted."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    return raise_own_priority(nice)
