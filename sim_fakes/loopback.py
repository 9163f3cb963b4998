"""Loopback addresses for simulators whose ports are fixed (a UR controller listens on 29999 and 30001-30004 at
one address, and ur-rtde 1.6 connects nowhere else).

Two test sessions on one machine must not share such an address: :func:`free_loopback_host` picks one at random
from 127.0.0.0/8 (Linux routes all of it to the loopback interface) and checks, by binding, that every port is
free there now.
"""

from __future__ import annotations

import ipaddress
import random
import socket
from collections.abc import Sequence

from drivers.ur_protocol import ALL_PORTS


def ports_free(host: str, ports: Sequence[int]) -> bool:
    """Whether every TCP port of ``ports`` can be bound at ``host`` right now."""
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the fakes bind
            try:
                sock.bind((host, port))
            except OSError:
                return False
    return True


def free_loopback_host(ports: Sequence[int] = ALL_PORTS, *, rng: random.Random | None = None, tries: int = 50) -> str:
    """A ``127.a.b.c`` address (``a`` >= 1: not the 127.0.0.N of the examples) with every port of ``ports`` free.

    Raises OSError when ``tries`` random addresses were all taken (or loopback aliases are not routed here)."""
    r = rng or random.SystemRandom()
    for _ in range(tries):
        host = str(
            ipaddress.IPv4Address(
                (127 << 24) | (r.randint(1, 254) << 16) | (r.randint(1, 254) << 8) | r.randint(1, 254)
            )
        )
        if ports_free(host, ports):
            return host
    raise OSError(f"no loopback address with ports {list(ports)} free after {tries} tries")
