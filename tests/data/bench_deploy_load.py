"""The deploy's own load on the recorded DUNE capture (docs/deploy.md, "Against real DUNE").

    PYTHONPATH=<tree> python tests/data/bench_deploy_load.py inprocess [used|all]
    PYTHONPATH=<tree> python tests/data/bench_deploy_load.py udp [used|all]

``inprocess``: every received datagram of the full capture through a dry-run Deploy's link
(pinned vehicles), clock = capture time: CPU per datagram, ``imc.lsf`` size.
``udp``: 30 s of the capture (from +40 s) re-sent over loopback UDP at the recorded pace by
a child process (from two sockets standing in for the otter and the AUV) to a dry-run deploy
running its real asyncio loop: the deploy's CPU share of one core. Without a ``used|all``
argument the ``log`` section is left at its default (for trees before ``log.lsf`` existed).
Capture: ``MPCASV_DUNE_TRAFFIC`` or /work/shared/data/dune-traffic/dune-traffic.jsonl.gz.
"""

from __future__ import annotations

import asyncio
import gzip
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CAPTURE = os.environ.get("MPCASV_DUNE_TRAFFIC",
                         "/work/shared/data/dune-traffic/dune-traffic.jsonl.gz")  # fmt: skip


def _received(t_from: float = 0.0, duration: float = 1e9) -> list[tuple[float, int, bytes]]:
    out, t0 = [], None
    for line in gzip.open(CAPTURE, "rt"):
        d = json.loads(line)
        if d.get("sent"):
            continue
        t0 = d["t_wall"] if t0 is None else t0
        if t_from <= d["t_wall"] - t0 <= t_from + duration:
            out.append((d["t_wall"], d["src_port"], bytes.fromhex(d["hex"])))
    return out


def _config(log_dir: str, lsf: str | None, port: int, otter: int, auv: int):
    from mpcasv.io.config import deploy_config_from_dict

    return deploy_config_from_dict({
        "identity": {"id": 0x4001, "name": "mpcasv-capture"},
        "origin": {"lat_deg": 41.1850, "lon_deg": -8.7062},
        "link": {"bind": "127.0.0.1", "port": port, "announce_to": [],
                 "heartbeat_period": 10.0},
        "vehicle": [{"role": "asv", "id": 0x0803, "address": f"127.0.0.1:{otter}"},
                    {"role": "auv", "id": 0x00D1, "address": f"127.0.0.1:{auv}"}],
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
        "watchdog": {"clock_slack_s": 60.0, "max_distance_m": 1e6},  # the widest allowed
        "log": {"dir": log_dir} | ({"lsf": lsf} if lsf else {}),
    })  # fmt: skip


def inprocess(lsf: str | None) -> None:
    from mpcasv.io.deploy import Deploy

    data = _received()
    tmp = tempfile.mkdtemp()
    dep = Deploy(_config(tmp, lsf, 6010, 6002, 6003), dry_run=True)
    clock = {"t": data[0][0]}
    dep.clock.now = lambda: clock["t"]
    c0, nxt = time.process_time(), data[0][0]
    for t, port, raw in data:
        clock["t"] = t
        while nxt <= t:
            dep.watch()
            nxt += 0.25
        dep.link.handle_datagram(raw, ("127.0.0.1", port))
    dep.jsonl.close()
    dep.lsf.close()
    cpu, span = time.process_time() - c0, data[-1][0] - data[0][0]
    size = (Path(tmp) / "imc.lsf").stat().st_size / 1e6
    print(f"inprocess lsf={lsf}: {len(data)} datagrams, {cpu:.2f} s CPU, "
          f"{1e6 * cpu / len(data):.1f} us/datagram; imc.lsf {size:.2f} MB = "
          f"{size / span * 60:.2f} MB/min")  # fmt: skip


def _blast(port: int) -> None:
    """Child: send the datagrams at the recorded pace after a line on stdin."""
    socks = {p: socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for p in (6002, 6003)}
    for s in socks.values():
        s.bind(("127.0.0.1", 0))
    rows = [r for r in _received(40.0, 30.0) if r[1] in socks]
    print(json.dumps({p: s.getsockname()[1] for p, s in socks.items()}), flush=True)
    sys.stdin.readline()
    w0, c0 = time.monotonic(), rows[0][0]
    for t, p, raw in rows:
        delay = (t - c0) - (time.monotonic() - w0)
        if delay > 0:
            time.sleep(delay)
        socks[p].sendto(raw, ("127.0.0.1", port))
    print(json.dumps({"sent": len(rows)}), flush=True)


def udp(lsf: str | None) -> None:
    from mpcasv.io.deploy import Deploy

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    child = subprocess.Popen([sys.executable, __file__, "_blast", str(port)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    ports = {int(k): v for k, v in json.loads(child.stdout.readline()).items()}
    tmp = tempfile.mkdtemp()

    async def main() -> None:
        dep = Deploy(_config(tmp, lsf, port, ports[6002], ports[6003]), dry_run=True)
        stop = asyncio.Event()
        task = asyncio.create_task(dep.run(stop))
        await asyncio.sleep(0.5)
        c0, w0 = time.process_time(), time.monotonic()
        child.stdin.write("go\n")
        child.stdin.flush()
        await asyncio.get_running_loop().run_in_executor(None, child.stdout.readline)
        await asyncio.sleep(0.2)
        cpu, wall = time.process_time() - c0, time.monotonic() - w0
        link = dep.link
        n = getattr(link, "datagrams", 0) or sum(
            sum(c.values()) for c in (link.accepted, link.ignored, link.rejects))
        stop.set()
        await task
        size = (Path(tmp) / "imc.lsf").stat().st_size / 1e6
        print(f"udp lsf={lsf}: {n} datagrams in {wall:.1f} s ({n / wall:.0f}/s): deploy CPU "
              f"{cpu:.2f} s = {100 * cpu / wall:.1f} % of a core, {1e6 * cpu / max(n, 1):.0f} "
              f"us/datagram; rejects {dict(link.rejects)}; imc.lsf {size:.2f} MB")  # fmt: skip

    asyncio.run(main())
    child.wait()


if __name__ == "__main__":
    mode, arg = sys.argv[1], (sys.argv[2] if len(sys.argv) > 2 else None)
    if mode == "_blast":
        _blast(int(arg))
    else:
        {"inprocess": inprocess, "udp": udp}[mode](arg)
