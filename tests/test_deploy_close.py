"""What the deploy loop, its IMC link, the SITL and the rehearsal helpers open is closed on
every way out: a failed start, a failed constructor, a cancelled run, a Deploy that is built
and never run (``close`` / ``with``). Found as ResourceWarnings (unclosed sockets, transports
and log files) in the test suite (session 31)."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest
from test_io_link import _cfg

from mpcasv.io.link import ImcLink
from mpcasv.io.logs import read_jsonl
from mpcasv.io.transport import Clock, UdpEndpoint

CASE3 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml"


def _events(path: Path, name: str) -> list[dict]:
    return [e for e in read_jsonl(path, "event") if e["event"] == name]


def _busy_udp_port() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s


# --- the link ---------------------------------------------------------------------------------


def test_a_link_whose_start_fails_closes_the_socket_it_had_bound(tmp_path, monkeypatch):
    def refuse(self, iface):
        raise OSError(f"no multicast on {iface}")

    monkeypatch.setattr(UdpEndpoint, "multicast_from", refuse)
    link = ImcLink(_cfg(tmp_path), Clock())
    with pytest.raises(OSError, match="no multicast"):
        asyncio.run(link.start())
    assert link.endpoint is not None and link.endpoint.closed
    assert link._tasks == []


def test_link_close_is_synchronous_and_repeatable(tmp_path):
    link = ImcLink(_cfg(tmp_path), Clock())

    async def main():
        await link.start()
        link.close()
        assert link.endpoint.closed and link._tasks == []

    asyncio.run(main())
    link.close()  # again, with the event loop gone: nothing to do, no error
