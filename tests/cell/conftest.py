"""The runner's rigs as fixtures for the tests of tests/cell (defined in tests/cell/runner_rig.py)."""

from tests.cell.runner_rig import fanuc, rig, ur5, ur5_cell  # noqa: F401  (fixtures the tests take by name)
