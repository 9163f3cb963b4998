"""drivers.priority: the I/O processes ask for nice -10 and get it where the OS lets them, never worse than now."""

from __future__ import annotations

import os
import subprocess
import sys

from drivers.priority import IO_PROCESS_NICE

PROBE = """
import os, sys
from drivers.priority import raise_own_priority
os.setpriority(os.PRIO_PROCESS, 0, int(sys.argv[1]))
before = os.getpriority(os.PRIO_PROCESS, 0)
granted = raise_own_priority(int(sys.argv[2]))
print(before, granted, os.getpriority(os.PRIO_PROCESS, 0))
"""


def _probe(start: int, ask: int) -> tuple[int, bool, int]:
    """In a child process (the test's own priority stays): its nice level set to ``start``, then the call."""
    out = subprocess.run([sys.executable, "-c", PROBE, str(start), str(ask)], capture_output=True, text=True,
                         check=True, timeout=60, cwd=os.getcwd())  # fmt: skip
    before, granted, after = out.stdout.split()
    return int(before), granted == "True", int(after)


def test_the_io_processes_ask_for_nice_minus_10() -> None:
    assert IO_PROCESS_NICE == -10


def test_a_better_level_is_granted_where_permitted_and_a_worse_one_is_never_taken() -> None:
    before, granted, after = _probe(5, -10)
    assert before == 5
    if os.geteuid() == 0:  # root may lower its nice level: it gets exactly the level asked for
        assert granted and after == -10
    else:  # an ordinary user may not: the call says so and the level stays
        assert not granted and after == 5
    # asking for a worse level than the current one keeps the current one (the call only ever improves it)
    before, granted, after = _probe(3, 10)
    assert (before, granted, after) == (3, True, 3)


ENTER = """
import os, signal
signal.signal(signal.SIGTERM, signal.SIG_IGN)  # as a parent that ignored it while starting this process passes on
from drivers.priority import enter_io_process
granted = enter_io_process()
print(signal.getsignal(signal.SIGINT) == signal.SIG_IGN, signal.getsignal(signal.SIGTERM) == signal.SIG_DFL, granted,
      os.getpriority(os.PRIO_PROCESS, 0))
"""


def test_an_io_process_leaves_ctrl_c_to_its_parent_ends_on_sigterm_and_asks_for_its_priority() -> None:
    out = subprocess.run([sys.executable, "-c", ENTER], capture_output=True, text=True, check=True, timeout=60)
    ignores_int, default_term, granted, nice = out.stdout.split()
    assert (ignores_int, default_term) == ("True", "True")
    if os.geteuid() == 0:
        assert granted == "True" and int(nice) == IO_PROCESS_NICE
    else:
        assert granted == "False"
