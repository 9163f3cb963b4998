"""Editing the example configs' text in tests: each line to change is found exactly once, and all are replaced at
once, so a new value that happens to contain another old one (a free port 50201 after "port = 5020") is left as
written."""

from __future__ import annotations

import re
import socket
from collections.abc import Iterable


def replace_each_once(text: str, swaps: Iterable[tuple[str, str]]) -> str:
    """``text`` with every ``old`` (each found exactly once in ``text``) replaced by its ``new``, simultaneously."""
    table = dict(swaps)
    for old in table:
        assert text.count(old) == 1, old
    pattern = re.compile("|".join(re.escape(old) for old in sorted(table, key=len, reverse=True)))
    return pattern.sub(lambda match: table[match.group(0)], text)


def free_port() -> int:
    """A TCP port on loopback that nothing listens on at the moment of asking."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])
