"""uvd.netports.free_port: a listener's port the kernel will not hand to anyone else."""

import socket

import pytest

from uvd.netports import ephemeral_range, free_port


@pytest.mark.parametrize("kind,host,family,stype", [
    ("tcp", "127.0.0.1", socket.AF_INET, socket.SOCK_STREAM),
    ("udp", "::1", socket.AF_INET6, socket.SOCK_DGRAM),
])
def test_free_port_is_bindable_and_outside_the_ephemeral_range(kind, host, family, stype):
    lo, hi = ephemeral_range()
    for _ in range(50):
        port = free_port(kind, host)
        assert 1024 <= port <= 65535
        assert not lo <= port <= hi, (port, lo, hi)
        with socket.socket(family, stype) as s:
            s.bind((host, port))


def _bindable(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_free_port_never_returns_a_bound_port(monkeypatch):
    taken = next(p for p in (free_port() for _ in range(50)) if p < 65535 and _bindable(p + 1))
    with socket.socket() as held:
        held.bind(("127.0.0.1", taken))
        held.listen()
        monkeypatch.setattr("uvd.netports._candidates", lambda: range(taken, taken + 2))
        assert {free_port() for _ in range(20)} == {taken + 1}
        monkeypatch.setattr("uvd.netports._candidates", lambda: range(taken, taken + 1))
        with pytest.raises(OSError, match="no free tcp port on 127.0.0.1"):
            free_port()


def test_free_port_refuses_an_unknown_kind():
    with pytest.raises(ValueError, match="kind must be 'tcp' or 'udp'"):
        free_port("sctp")
