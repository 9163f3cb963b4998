"""Disjoint sets: joins chain into groups, and the first item of a group stays its representative."""

from __future__ import annotations

from perception.fine.groups import Groups


def test_joins_chain_into_groups() -> None:
    g = Groups(range(6))
    g.join(0, 1)
    g.join(2, 3)
    g.join(1, 3)  # 0-1 and 2-3 become one group
    assert {g.find(k) for k in (0, 1, 2, 3)} == {0}
    assert g.find(4) == 4 and g.find(5) == 5
    g.join(5, 0)
    assert {g.find(k) for k in range(4)} | {g.find(5)} == {5}


def test_any_hashable_items() -> None:
    g = Groups(["a", "b", "c"])
    g.join("c", "a")
    assert g.find("a") == "c" and g.find("b") == "b"
