"""What the deploy loop, its IMC link, the SITL and the rehearsal helpers open is closed on
every way out: a failed start, a failed constructor, a cancelled run, a Deploy that is built
and never run (``close`` / ``with``). Found as ResourceWarnings (unclosed sockets, transports
and log files) in the test suite (session 31)."""

from __future__ import annotations

import asyncio
import dataclasses
import socket
import subprocess
from pathlib import Path

import imcpy
import pytest
from test_io_link import ASV_ID, Fake, _cfg, _until, run

from mpcasv.io import deploy as deploy_mod
from mpcasv.io.deploy import Deploy
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


# --- the link -------------------------------------------------------------------------------------


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


# --- the deploy loop ------------------------------------------------------------------------------


def test_a_deploy_is_a_context_manager_that_closes_its_logs(tmp_path):
    with Deploy(_cfg(tmp_path), dry_run=True) as dep:
        dep.jsonl.write({"kind": "event", "event": "x"})
    assert dep.jsonl.closed and dep.lsf.closed
    dep.close()  # repeatable


def test_a_deploy_whose_constructor_fails_closes_what_it_had_opened(tmp_path, monkeypatch):
    opened = []

    class Lsf(deploy_mod.LsfWriter):
        def __init__(self, path):
            super().__init__(path)
            opened.append(self)

    monkeypatch.setattr(deploy_mod, "LsfWriter", Lsf)
    (tmp_path / "log" / "deploy.jsonl").mkdir(parents=True)  # the JSON log cannot be opened
    with pytest.raises(IsADirectoryError):
        Deploy(_cfg(tmp_path), dry_run=True)
    assert len(opened) == 1 and opened[0].closed


def test_a_deploy_whose_constructor_fails_stops_the_solver_workers_it_had_started(
        tmp_path, monkeypatch):  # fmt: skip
    """Field mode's workers start before the logs and the link are made: a failure after
    them stops them (they are processes, not just descriptors)."""
    calls = []

    class Controller:  # what the deploy uses of an MPC before its first step
        def reset(self, n):
            pass

        def use_deadline(self, factory=None):
            calls.append("started")

        def close(self):
            calls.append("closed")

    def fail(cfg):
        raise RuntimeError("no plans")

    monkeypatch.setattr(deploy_mod, "build_controller", lambda cfg, log: Controller())
    monkeypatch.setattr(deploy_mod, "known_plans", fail)
    with pytest.raises(RuntimeError, match="no plans"):
        Deploy(_cfg(tmp_path), dry_run=True)
    assert calls == ["started", "closed"]


def test_a_deploy_whose_controller_cannot_be_built_raises_that(tmp_path, monkeypatch):
    def fail(cfg, log):
        raise RuntimeError("no controller")

    monkeypatch.setattr(deploy_mod, "build_controller", fail)
    with pytest.raises(RuntimeError, match="no controller"):  # not close()'s own error
        Deploy(_cfg(tmp_path), dry_run=True)


def _run_on_a_busy_port(tmp_path: Path, prepare=lambda dep: None) -> Deploy:
    """A dry-run Deploy whose link's port is taken, ``prepare(dep)`` before its run, run: the
    bind fails (OSError, checked); returns the Deploy."""
    busy = _busy_udp_port()
    try:
        cfg = _cfg(tmp_path)
        cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link,
                                                                port=busy.getsockname()[1]))
        dep = Deploy(cfg, dry_run=True)
        prepare(dep)
        with pytest.raises(OSError):
            asyncio.run(dep.run(asyncio.Event()))
    finally:
        busy.close()
    return dep


def test_a_run_whose_link_cannot_bind_is_aborted_and_closes_everything(tmp_path):
    dep = _run_on_a_busy_port(tmp_path)
    assert dep.jsonl.closed and dep.lsf.closed
    log = tmp_path / "log" / "deploy.jsonl"
    (aborted,) = _events(log, "aborted")
    assert aborted["reason"].startswith("OSError")
    summary = read_jsonl(log)[-1]
    assert summary["kind"] == "summary" and summary["aborted"] == aborted["reason"]


def test_an_abort_that_cannot_write_its_summary_raises_the_runs_own_error(tmp_path):
    def broken(**extra):
        raise RuntimeError("disk full")

    dep = _run_on_a_busy_port(tmp_path, lambda dep: setattr(dep, "write_summary", broken))
    assert dep.jsonl.closed and dep.lsf.closed


def test_a_cancelled_run_is_aborted_closes_everything_and_sends_no_mandone(tmp_path):
    """A run cancelled (not stopped: no Ctrl-C, SIGTERM or duration) after it had started
    FollowReference: event ``aborted``, the summary's ``aborted``, every socket and log
    closed; nothing more is sent to the ASV (no standby, no MANDONE: the shutdown that
    waits for DUNE's answer is the stop's, not a cancellation's)."""
    got = {}

    async def main():
        dep = Deploy(_cfg(tmp_path), dry_run=False)
        task = asyncio.create_task(dep.run(asyncio.Event()))
        assert await _until(lambda: dep.link.endpoint is not None)
        asv = await Fake("fake-asv", ASV_ID, imcpy.SystemType.USV).open()
        to = dep.link.endpoint.address
        asv.announce(to, dep.clock.now())
        assert await _until(lambda: bool(dep.link.asv.addresses))
        dep.started = True  # as if FollowReference were running
        await asyncio.sleep(0.05)
        before = len(asv.received)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await asyncio.sleep(0.1)
        got["after"] = [type(m).__name__ for m in asv.received[before:]]
        # the deploy's tasks (watchdogs, log flushes) and the link's are ended too
        assert asyncio.all_tasks() == {asyncio.current_task()}
        return dep

    dep = run(main)
    assert "Reference" not in got["after"]
    assert dep.link.endpoint.closed and dep.jsonl.closed and dep.lsf.closed
    assert dep.link._tasks == []
    log = tmp_path / "log" / "deploy.jsonl"
    (aborted,) = _events(log, "aborted")
    assert aborted["reason"] == "cancelled"
    assert not _events(log, "final_standby")
    summary = read_jsonl(log)[-1]
    assert summary["kind"] == "summary" and summary["aborted"] == "cancelled"


def test_a_stopped_run_is_not_aborted(tmp_path):
    async def main():
        dep = Deploy(_cfg(tmp_path), dry_run=True)
        stop = asyncio.Event()
        stop.set()
        return dep, await dep.run(stop)

    dep, summary = asyncio.run(main())
    assert "aborted" not in summary
    assert not _events(tmp_path / "log" / "deploy.jsonl", "aborted")
    assert dep.link.endpoint.closed and dep.jsonl.closed and dep.lsf.closed


# --- the SITL -------------------------------------------------------------------------------------


def _sitl(tmp_path):
    from mpcasv.io.sitl import Sitl, SitlOptions
    from mpcasv.sim.scenario import load_scenario

    return Sitl(load_scenario(CASE3), SitlOptions(speedup=20.0, discovery_port=0, out=tmp_path))


def test_a_sitl_whose_start_fails_closes_its_sockets_and_logs(tmp_path, monkeypatch):
    from mpcasv.io.simvehicle import SimVehicle

    sitl = _sitl(tmp_path)
    real = SimVehicle.open

    async def open_(self, host):
        if self.role == "auv":
            raise OSError("port taken")
        await real(self, host)

    monkeypatch.setattr(SimVehicle, "open", open_)
    with pytest.raises(OSError, match="port taken"):
        asyncio.run(sitl.run(asyncio.Event()))
    assert sitl.discovery.closed
    assert all(v.endpoint is None and v.announcer is None for v in sitl.vehicles)
    assert sitl.jsonl.closed and sitl.lsf.closed
    assert _events(tmp_path / "sitl.jsonl", "aborted")


def test_a_cancelled_sitl_closes_its_sockets_and_logs(tmp_path):
    sitl = _sitl(tmp_path)

    async def main():
        task = asyncio.create_task(sitl.run(asyncio.Event()))
        assert await _until(lambda: sitl.epoch > 0, 10.0)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await asyncio.sleep(0.05)
        assert asyncio.all_tasks() == {asyncio.current_task()}  # its log flusher ended too

    asyncio.run(main())
    assert sitl.discovery.closed
    assert all(v.endpoint is None for v in sitl.vehicles)
    assert sitl.jsonl.closed and sitl.lsf.closed
    assert [e["reason"] for e in _events(tmp_path / "sitl.jsonl", "aborted")] == ["cancelled"]
    assert not (tmp_path / "run").exists()


def test_sitl_close_is_repeatable(tmp_path):
    sitl = _sitl(tmp_path)
    sitl.close()
    sitl.close()
    assert sitl.jsonl.closed and sitl.lsf.closed


# --- the rehearsal helpers ------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["sitl", "deploy"])
def test_the_rehearsal_helpers_keep_no_stderr_file_open(tmp_path, monkeypatch, which):
    """The child has its own copy of the stderr file; ours is closed once it is started."""
    from mpcasv.io import rehearsal

    given = []

    class Popen:
        def __init__(self, cmd, stdout=None, stderr=None):
            given.append(stderr)

    monkeypatch.setattr(subprocess, "Popen", Popen)
    if which == "sitl":
        rehearsal.start_sitl(CASE3, tmp_path / "sitl", wait=False)
    else:
        rehearsal.start_deploy({"log": {"dir": str(tmp_path)}}, tmp_path)
    assert len(given) == 1 and given[0].closed
