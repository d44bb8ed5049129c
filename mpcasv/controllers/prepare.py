"""Compile what controllers need once, before a sweep or a simulation starts (issue 12 item 8).

An MPC loads a compiled library from the cache (``~/.cache/mpcasv/mpc``, or ``$MPCASV_CACHE``);
a missing one is compiled on first use, which takes tens of seconds per library (more for a
stiff hull's many plan sub-steps; docs/mpc.md, "Known problems"). Before any worker starts,
:func:`prepare` lists the libraries the jobs need that are not in the cache, says so once
with an estimate, and compiles them here with a progress line each, so the workers load them
and the sweep's progress bar does not sit at 0 % without a word.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterable
from typing import Any

from mpcasv.config import resolve
from mpcasv.controllers.registry import (
    Boat,
    check_boat,
    checked_preset,
    preset_used,
)


def needed_libraries(builds: Iterable[tuple[str, int, Any, Any, Boat | None]]) -> list:
    """Libraries (see :class:`mpcasv.mpc.prepare.Library`) of the controllers
    ``(name, n_auv, preset, overrides, boat)``, one per cache path, in first-seen order."""
    seen: dict = {}
    for name, n_auv, preset, overrides, boat in builds:
        # before compiling a library it cannot use (e.g. the visiting order's AUV limit)
        kind, params = checked_preset(name, n_auv, preset, overrides)
        if kind.libraries is None:
            continue
        if boat is not None:
            check_boat(params, boat, str(resolve("presets", preset_used(name, preset))))
        for lib in kind.libraries(params, n_auv, boat):
            seen.setdefault(lib.path, lib)
    return list(seen.values())


def about(seconds: float) -> str:
    """``seconds`` as a person reads an estimate: ``"40 s"`` below two minutes, else
    ``"4 min"``."""
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def _ticker(bar, stop: threading.Event, every: float) -> None:
    """Fill the bar with the elapsed time every ``every`` s (up to 99 % of the estimate;
    tqdm shows the elapsed time itself beside it)."""
    t0 = time.perf_counter()
    while not stop.wait(every):
        bar.n = min(time.perf_counter() - t0, bar.total * 0.99)
        bar.refresh()


def prepare(libraries: list, quiet: bool = False, file=None) -> list:
    """Compile the libraries not in the cache, one after the other, with a message first and
    a progress line each (elapsed time against the estimate). Returns those compiled.

    Raises
    ------
    RuntimeError
        If a compile fails (no compiler: the message says how to run without).
    """
    from tqdm import tqdm

    file = file or sys.stderr
    missing = [lib for lib in libraries if not lib.cached]
    if not missing:
        return []
    total = sum(lib.estimate_s for lib in missing)
    folder = missing[0].path.parent
    print(f"first run: {len(missing)} MPC librar{'y' if len(missing) == 1 else 'ies'} to compile "
          f"(not in the cache {folder}); this happens once per problem, about {about(total)} "
          "on an idle machine (longer on a busy one):", file=file, flush=True)  # fmt: skip
    for lib in missing:
        print(f"  {lib.label}: {lib.path.name} (about {about(lib.estimate_s)})", file=file)
    # a log file gets a line every 30 s, not a frame every half second
    every = 0.5 if getattr(file, "isatty", lambda: False)() else 30.0
    for i, lib in enumerate(missing, 1):
        bar = tqdm(total=lib.estimate_s, desc=f"compiling {i}/{len(missing)} {lib.label}",
                   unit="s", disable=quiet, file=file, dynamic_ncols=True, mininterval=every,
                   bar_format="{desc}: {bar} {elapsed} (about " + about(lib.estimate_s)
                   + " on an idle machine)")  # fmt: skip
        stop = threading.Event()
        ticker = threading.Thread(target=_ticker, args=(bar, stop, every), daemon=True)
        ticker.start()
        t0 = time.perf_counter()
        try:
            lib.compile(log=lambda msg: None)  # the bar and the line below say it
        finally:
            stop.set()
            ticker.join()
            bar.close()
        print(f"  compiled {lib.label} in {time.perf_counter() - t0:.0f} s -> {lib.path}",
              file=file, flush=True)  # fmt: skip
    return missing
