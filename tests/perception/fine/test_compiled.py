"""perception.fine.compiled: the warm-up compiles every type of every kernel a detection calls, so that no
detection compiles one (seconds) in the middle of its timing or of a cell's job."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "ribs"

_PROBE = """
import json, sys
from numba.core.registry import CPUDispatcher
import perception.fine as fine, importlib, pkgutil
from perception.fine.compiled import warm_up

def kernels():
    out = {}
    for m in pkgutil.iter_modules(fine.__path__):
        mod = importlib.import_module("perception.fine." + m.name)
        for name, f in vars(mod).items():
            if isinstance(f, CPUDispatcher) and f.__module__ == mod.__name__:
                out[mod.__name__ + "." + name] = sorted(str(s) for s in f.signatures)
    return out

warm_up()
before = kernels()
from perception.capture import load_capture
from perception.detect import DetectParams, detect
res = detect(load_capture(sys.argv[1]), DetectParams())
print(json.dumps({"before": before, "after": kernels(), "seams": len(res.seams)}))
"""


def test_a_detection_after_the_warm_up_compiles_no_kernel_type() -> None:
    """The bundled ribs in a fresh process (the one whose kernels the warm-up loaded): after its detection
    every compiled kernel holds exactly the types it held after the warm-up, and some kernels ran."""
    out = subprocess.run([sys.executable, "-c", _PROBE, str(SAMPLE)], capture_output=True, text=True, timeout=300,
                         check=True)  # fmt: skip
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["seams"] == 10
    assert got["after"] == got["before"], {k: v for k, v in got["after"].items() if got["before"].get(k) != v}
    assert sum(len(v) for v in got["before"].values()) >= 8
