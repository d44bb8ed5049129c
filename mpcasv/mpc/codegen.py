"""Compiled NLP functions, cached on disk.

The functions of :func:`mpcasv.mpc.derivatives.nlp_functions` are generated as C
(``casadi.CodeGenerator``), compiled once into a shared library and kept in the cache folder
(``$MPCASV_CACHE`` or ``~/.cache/mpcasv``), keyed by a SHA-256 of the functions' serialised
definition, the solver, the compiler flags, the CasADi version and the CPU. Another process
(or run) with the same problem loads the library without compiling; a changed weight, horizon
or vessel parameter changes the key. Compilation holds an exclusive lock on
``<library>.lock`` (``fcntl.flock``), so parallel workers needing the same library compile it
once (the others wait, then load it), and writes to a temporary name and renames, so no process
ever loads a half-written library.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as ca

_LOADED: dict[tuple[str, str, str], Path] = {}


def cache_dir() -> Path:
    """The folder holding compiled libraries (created if missing)."""
    root = os.environ.get("MPCASV_CACHE") or Path.home() / ".cache" / "mpcasv"
    path = Path(root) / "mpc"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


#: how the generated C's OpenMP loops get their thread count (``thread_cflags``)
_THREADS_DEFINE = "MPCASV_THREADS"
_OMP_LOOP = "#pragma omp parallel for"
#: version of ``with_thread_count``'s rewrite, in the flags and so in the cache key: change it
#: when the rewrite changes, or libraries compiled with the old one are loaded from the cache
_OMP_REWRITE = 1


def thread_cflags(cflags: str, threads: int) -> str:
    """Compiler flags for a library whose horizon loops run on ``threads`` threads
    (``SolverParams.threads``): ``cflags`` unchanged for 1, else with ``-fopenmp`` and the
    thread count, which the generated OpenMP loops are given as ``num_threads`` (so a
    library's parallelism is fixed by its flags, part of the cache key, not by the
    environment)."""
    if threads <= 1:
        return cflags
    # -z nodelete: the library stays mapped after dlclose, for OpenMP's threads outlive it
    # (unloaded, the process crashed at exit)
    return (f"{cflags} -fopenmp -D{_THREADS_DEFINE}={int(threads)} "
            f"-DMPCASV_OMP_REWRITE={_OMP_REWRITE} -Wl,-z,nodelete")


def with_thread_count(c_source: str, cflags: str) -> str:
    """The generated C with its OpenMP loops given the thread count of ``cflags``
    (:func:`thread_cflags`; CasADi writes them without one), statically scheduled: one
    equal share of the stages per thread. Unchanged without that flag."""
    if f"-D{_THREADS_DEFINE}=" not in cflags:
        return c_source
    return c_source.replace(_OMP_LOOP, f"{_OMP_LOOP} num_threads({_THREADS_DEFINE}) "
                                       "schedule(static)")  # fmt: skip


def library_key(functions: dict[str, ca.Function], solver: str, cflags: str) -> str:
    """SHA-256 (hex, 24 characters) of everything that determines the compiled library."""
    h = hashlib.sha256()
    for part in (ca.__version__, solver, cflags, _cpu(), platform.machine()):
        h.update(part.encode())
    for name in sorted(functions):
        h.update(name.encode())
        h.update(functions[name].serialize().encode())
    return h.hexdigest()[:24]


def library_path(functions: dict[str, ca.Function], solver: str, cflags: str) -> Path:
    """Where the library with ``functions`` is (or will be) in the cache."""
    return _library_file(solver, library_key(functions, solver, cflags))


def _library_file(solver: str, key: str) -> Path:
    return cache_dir() / f"mpc_{solver}_{key}.so"


def _lock_file(folder: Path, stem: str) -> Path:
    """The lock a compile of library ``<stem>.so`` holds (``fcntl.flock``)."""
    return folder / f"{stem}.so.lock"


def compiled_library(functions: dict[str, ca.Function], solver: str, cflags: str,
                     compiler: str = "gcc", log=print) -> Path:  # fmt: skip
    """Path of the shared library with ``functions``: from the cache, or compiled now.

    Raises
    ------
    RuntimeError
        If no C compiler is found or compilation fails (the message says how to run without).
    """
    key = library_key(functions, solver, cflags)
    memo = (key, solver, cflags)
    if memo in _LOADED and _LOADED[memo].exists():
        return _LOADED[memo]
    target = _library_file(solver, key)
    folder = target.parent
    if not target.exists():
        with open(_lock_file(folder, target.stem), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # one compile per library across processes
            if not target.exists():  # another process may have compiled it meanwhile
                _compile(functions, target, compiler, cflags, solver, log)
    _LOADED[memo] = target
    return target


def write_source(functions: dict[str, ca.Function], src: Path, cflags: str) -> Path:
    """Generate the C of ``functions`` into ``src`` (what the cache compiles with ``cflags``:
    OpenMP loops given their thread count, :func:`with_thread_count`)."""
    gen = ca.CodeGenerator(src.name)
    for fun in functions.values():
        gen.add(fun)
    gen.generate(str(src.parent) + os.sep)
    src.write_text(with_thread_count(src.read_text(), cflags))
    return src


def _remove_abandoned(folder: Path, stem: str) -> None:
    """Remove the temporary folders (``<stem>.tmp*``) that compiles killed by a signal left in
    the cache (no cleanup ran): this library's (its lock is held by the caller, so nobody
    else is compiling it), and any other library's whose lock is free (a compile in progress
    holds it; a killed one's lock was released by the kernel). Folders of the naming before
    session 21 (``tmp*``, no library named) are left alone."""
    for left in folder.glob("mpc_*.tmp*"):
        other = left.name.split(".tmp")[0]
        if other == stem:
            shutil.rmtree(left, ignore_errors=True)
            continue
        try:
            with open(_lock_file(folder, other), "a") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)  # released at close
                shutil.rmtree(left, ignore_errors=True)
        except OSError:  # being compiled now (lock held), or not ours to touch
            continue


def _compile(functions: dict[str, ca.Function], target: Path, compiler: str, cflags: str,
             solver: str, log) -> None:
    """Generate C for ``functions`` and compile it into ``target`` (atomic rename), in a
    temporary folder ``<target stem>.tmp*`` beside it; called under the library's lock."""
    folder, stem = target.parent, target.stem
    if shutil.which(compiler) is None:
        raise RuntimeError(f"C compiler {compiler!r} not found: install it or set "
                           "solver.compiled = false in the MPC preset")  # fmt: skip
    t0 = time.perf_counter()
    _remove_abandoned(folder, stem)
    with tempfile.TemporaryDirectory(dir=folder, prefix=f"{stem}.tmp") as tmp:
        src = write_source(functions, Path(tmp) / f"{stem}.c", cflags)
        out = Path(tmp) / target.name
        cmd = [compiler, *shlex.split(cflags), "-fPIC", "-shared", str(src), "-o", str(out),
               "-lm"]  # fmt: skip
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"compiling the MPC functions failed: {' '.join(cmd)}\n"
                               f"{res.stderr[-2000:]}")  # fmt: skip
        os.replace(out, target)  # atomic: concurrent processes see all or nothing
    log(f"mpc: compiled {target.name} ({solver}, {cflags}) in "
        f"{time.perf_counter() - t0:.0f} s")  # fmt: skip
