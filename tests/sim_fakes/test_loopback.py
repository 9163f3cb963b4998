"""sim_fakes/loopback.py: a loopback address per test session for simulators with fixed ports."""

from __future__ import annotations

import ipaddress
import random
import socket

import pytest

from sim_fakes.loopback import free_loopback_host, ports_free


def test_a_free_host_is_in_127_slash_8_outside_the_examples_and_its_ports_bind() -> None:
    host = free_loopback_host()
    address = ipaddress.IPv4Address(host)
    assert address.is_loopback and address.packed[1] >= 1  # 127.a.b.c with a >= 1: not 127.0.0.N
    assert ports_free(host, (29999, 30001, 30002, 30003, 30004))
    with socket.socket() as sock:
        sock.bind((host, 30004))
        sock.listen()
        assert not ports_free(host, (29999, 30004))  # taken: refused


def test_a_seeded_choice_is_repeatable_and_a_taken_address_is_skipped() -> None:
    first = free_loopback_host((30004,), rng=random.Random(7))
    assert free_loopback_host((30004,), rng=random.Random(7)) == first
    with socket.socket() as sock:
        sock.bind((first, 30004))
        sock.listen()
        second = free_loopback_host((30004,), rng=random.Random(7))
    assert second != first and ipaddress.IPv4Address(second).is_loopback


def test_no_free_address_after_the_tries_is_an_os_error() -> None:
    class Same(random.Random):
        def randint(self, a: int, b: int) -> int:
            return 9

    with socket.socket() as sock:
        sock.bind(("127.9.9.9", 30004))
        sock.listen()
        with pytest.raises(OSError, match=r"no loopback address with ports \[30004\] free after 3 tries"):
            free_loopback_host((30004,), rng=Same(), tries=3)
