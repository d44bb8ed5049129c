"""Ctrl-C (SIGINT) in the phases of ``mpcasv sitl`` before its event loop runs.

A terminal's Ctrl-C has the default disposition (KeyboardInterrupt); the child processes set
it explicitly, as a test runner's worker may ignore SIGINT and its children inherit that.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# mpcasv sitl, its world's build made slow (3 s) with a Ctrl-C at its start
_SLOW_BUILD = textwrap.dedent("""
    import os, signal, sys, time
    signal.signal(signal.SIGINT, signal.default_int_handler)  # a terminal's Ctrl-C
    import mpcasv.sim.world as world
    from mpcasv.cli import main
    real = world.World.__init__
    def slow(self, *args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while the world is being built
        time.sleep(3.0)
        print("built on after the Ctrl-C", flush=True)
        real(self, *args, **kwargs)
    world.World.__init__ = slow
    sys.exit(main(sys.argv[1:]))
""")


def test_sitl_ctrl_c_while_the_world_is_built_stops_it_at_once(tmp_path):
    """Before session 26 the SITL built its world inside the event loop, before its signal
    handlers: asyncio's own SIGINT handler only cancelled the main task, so the build ran on
    to its end (here 3 s more) and the SITL then stopped at its first await, without its
    shutdown. Now the build is interrupted at once: exit 130, nothing written."""
    out = tmp_path / "sitl"
    scenario = ROOT / "experiments" / "scenarios" / "case3.toml"
    cmd = [sys.executable, "-c", _SLOW_BUILD, "sitl", str(scenario),
           "--speedup", "20", "--hold", "--quiet", "--discovery-port", "0", "--base-port", "0",
           "--out", str(out)]  # fmt: skip
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert "built on after the Ctrl-C" not in res.stdout, "the Ctrl-C waited for the build"
    assert res.returncode == 130, res.stderr[-2000:]
    assert res.stderr.strip().splitlines()[-1] == "mpcasv sitl: interrupted"
    assert not (out / "sitl.jsonl").exists()
