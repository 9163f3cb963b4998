"""Disjoint sets (union-find with path halving): which items end up in one group after pairwise joins."""

from __future__ import annotations

from collections.abc import Hashable, Iterable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)


class Groups(Generic[K]):
    """Each of ``items`` starts in a group of its own; :meth:`join` merges two groups."""

    def __init__(self, items: Iterable[K]) -> None:
        self._parent: dict[K, K] = {k: k for k in items}

    def find(self, k: K) -> K:
        """The representative of ``k``'s group (the first item joined into it stays it)."""
        parent = self._parent
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    def join(self, a: K, b: K) -> None:
        """Put ``b``'s group into ``a``'s (``a``'s representative stays)."""
        self._parent[self.find(b)] = self.find(a)
