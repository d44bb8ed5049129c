"""Solves that can be abandoned: the field mode's hard deadline (issue 16 item 5).

In the field a solve may never hold the control step beyond its budget. A solve running in
this process cannot be abandoned: a native call that hangs (fatrop has looped forever on NaN
trial points, docs/mpc.md "Known problems") cannot be interrupted from Python, and a thread
running it cannot be stopped (it would keep a core and the solver's memory for ever; CasADi
releases the GIL during numeric calls only from its 3.7 line on, casadi/casadi#2955). So the
solver runs in a worker process: the controller sends the parameters and the warm start
through a pipe and waits at most the remaining budget. A worker that has not answered by then
is killed (SIGKILL) and replaced by a spare that was started beforehand (its compiled library
already loaded), so the next step has a ready solver; a new spare is started at once.

A worker started from the main thread dies with the process that started it (Linux,
:func:`_die_with`): one left inside a hung native solve would otherwise spin for ever.

The warm start stays in the controller (the previous plan moved one period ahead), so the
step after an overrun starts warm whatever happened to the worker.

In the field (:meth:`mpcasv.mpc.solving.Solving.use_deadline`) the deadline is wall
time. Simulation's hang guard (:meth:`~mpcasv.mpc.solving.Solving.use_hang_guard`)
judges a solve by the CPU time its worker has spent on it instead (``cpu_timeout``): a hung
fatrop spins (docs/mpc.md "Known problems"), while a solve starved by the machine's load uses
little CPU, so the load does not decide which solve is abandoned (wall-clock time does not
change a simulated decision); the wall clock only ends a worker that has used no CPU at all
for a long time (stopped or blocked), not counting time in which this process was stopped
itself. What is left to chance: the CPU time is read every ``CPU_POLL_S`` s, so a solve that
would end within a poll of the limit may or may not be abandoned, and the CPU a unit of work
takes varies a little with load (caches, shared cores); with ``hang_s`` = 10 s of CPU
against solves of at most about a second, neither has been seen to matter. The limit counts
all the worker's threads (``solver.threads``).
"""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import psutil

from mpcasv.mpc.solvers import SolveResult

_READY = "ready"
#: after a missed deadline the new spare worker is started this much later (s), in the idle
#: part of the control period: starting a process holds the interpreter for 4-45 ms (measured
#: at load 8 on 2 cores), which would otherwise be spent on the step that missed its deadline
SPARE_DELAY_S = 0.1
#: how often a solve judged by its worker's CPU time (``cpu_timeout``) reads that time (s)
CPU_POLL_S = 0.2
#: how to start Dask workers that may run an MPC (not daemons), or do without its hang guard
DAEMON_FIX = (
    "start the workers with DASK_DISTRIBUTED__WORKER__DAEMON=False (or 'dask worker "
    "--no-nanny', one worker per command), or set solver.hang_s = 0 (no hang guard)"
)
#: why a daemon process (a Dask worker under its nanny) cannot run an MPC with its hang
#: guard: it may not start the solver's worker process
DAEMON_REFUSED = (
    "this process is a daemon, which may not start the MPC's solver process (the hang "
    f"guard, solver.hang_s > 0); a Dask worker under its nanny is one: {DAEMON_FIX}"
)


def cpu_s(proc) -> float:
    """CPU time (user + system, all threads, s) process ``proc`` has used; NaN if it cannot
    be read (not started yet, gone, or psutil refused): unknown, never taken for progress nor
    for a limit reached."""
    if getattr(proc, "pid", None) is None:  # psutil.Process(None) would be this process
        return math.nan
    try:
        t = psutil.Process(proc.pid).cpu_times()
    except (psutil.Error, ValueError, TypeError):
        return math.nan
    return t.user + t.system


def _die_with(parent: int | None) -> None:  # pragma: no cover - runs in the worker
    """Linux: have the kernel SIGKILL this process when the thread that started it ends
    (``PR_SET_PDEATHSIG``). A worker whose parent is gone would otherwise live on, and one
    stuck in a hung native solve (which may hold the GIL: a Python thread ran 89 of 511
    10-ms ticks during a 5-s CasADi 3.8.2 call, session 14) spins for
    ever: a killed ``mpcasv compare`` left one at 70 % of a core for 20 min (session 14).
    ``parent``: the parent's pid if it was started from its main thread (None: from another
    thread, whose end would kill it; the field mode's spares, in a long-lived process)."""
    if parent is None or not sys.platform.startswith("linux"):
        return
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) != 0:  # 1: PR_SET_PDEATHSIG
        return
    if os.getppid() != parent:  # the parent died before the call: nobody will ask
        os._exit(1)


def _serve(factory: Callable, conn, parent: int | None = None) -> None:  # pragma: no cover
    """Worker process: build the solver, say so, then answer solve requests until None
    (``parent``: :func:`_die_with`). It ignores SIGINT: a Ctrl-C at the terminal reaches the
    whole process group, and the parent, which handles it, stops its workers (``close``,
    or as daemons at its exit); a worker's own ``KeyboardInterrupt`` only printed its
    traceback over the parent's one-line message."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with(parent)
    try:
        solver = factory()
    except BaseException as exc:
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(_READY)
    while True:
        try:
            msg = conn.recv()
        except EOFError:
            return
        if msg is None:
            return
        try:
            conn.send(solver.solve(*msg))
        except Exception as exc:
            conn.send(("error", f"{type(exc).__name__}: {exc}"))


class _Worker:
    """One solver process and the parent's end of its pipe."""

    def __init__(self, factory: Callable, ctx, background: bool = False, delay: float = 0.0):
        self.conn, self._child = ctx.Pipe()
        # started from the main thread: it dies with this process (a thread's spare cannot)
        main = not background and threading.current_thread() is threading.main_thread()
        self.proc = ctx.Process(target=_serve, args=(factory, self._child,
                                                     os.getpid() if main else None),
                                daemon=True, name="mpcasv-mpc-solver")  # fmt: skip
        self.ready = False
        self._started = threading.Event()
        if background:  # starting a process takes tens of ms (and the GIL): not on the step's time
            threading.Thread(target=self._start, args=(delay,), daemon=True).start()
        else:
            self._start()

    def _start(self, delay: float = 0.0) -> None:
        time.sleep(delay)
        try:
            self.proc.start()
        finally:
            self._child.close()
            self._started.set()

    def wait_ready(self, timeout: float) -> bool:
        """Consume the worker's ready message if it comes within ``timeout`` s.

        Raises
        ------
        RuntimeError
            The worker could not build its solver (its message).
        """
        if self.ready:
            return True
        if not self.conn.poll(max(timeout, 0.0)):
            return False
        try:
            msg = self.conn.recv()
        except EOFError:
            self.proc.join(timeout=5.0)
            raise RuntimeError("MPC solver worker exited before it was ready (exit code "
                               f"{self.proc.exitcode}; with 'spawn' a script that builds a "
                               "field-mode controller needs an if __name__ == '__main__' guard)"
                               ) from None  # fmt: skip
        if msg != _READY:
            raise RuntimeError(f"MPC solver worker failed to start: {msg[1]}")
        self.ready = True
        return True

    def kill(self, wait: bool = True) -> None:
        """SIGKILL the worker; ``wait``: also reap it (else :meth:`reap` later)."""
        self._started.wait(timeout=30.0)
        if self.proc.pid is not None and self.proc.is_alive():
            self.proc.kill()
        self.conn.close()
        if wait:
            self.reap()

    def reap(self) -> None:
        if self.proc.pid is not None:
            self.proc.join(timeout=5.0)

    def stop(self) -> None:
        self._started.wait(timeout=30.0)
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.proc.join(timeout=2.0)
        self.kill()


class DeadlineSolver:
    """A solver in a worker process, with a deadline per call and a spare worker.

    Parameters
    ----------
    factory : callable
        Picklable, no arguments; returns an object with ``solve(p, w0, lam_x0, lam_g0) ->
        SolveResult`` (built in the worker: e.g. ``functools.partial`` of a module-level
        function that builds the OCP and loads the compiled library from the cache).
    start_timeout : float
        Seconds to wait for the first worker to be ready at construction.
    spare : bool
        Keep a spare worker ready (the field: a killed worker's successor is ready at once).
        False (simulation's hang guard, where wall time decides nothing): no spare process;
        a killed worker's successor is started at the next solve and waited for (the spare
        imported and built the problem for nothing in every run: ~10 % of an MPC run's CPU
        in a profile of Case 3).

    Raises
    ------
    RuntimeError
        The first worker did not start within ``start_timeout`` or could not build its solver;
        or this process is a daemon, which may not start one (a Dask worker under its nanny:
        start the workers with ``DASK_DISTRIBUTED__WORKER__DAEMON=False``, docs/experiments.md).

    Attributes
    ----------
    abandoned : int
        Solves abandoned at their deadline (their worker killed).
    last_error : str or None
        Why the last solve failed in its worker (the exception, or "solver worker died");
        None if it returned or was abandoned. Its result's ``status`` says the same.
    last_abandon : {"wall", "cpu", "idle"} or None
        Which limit abandoned the last solve (:meth:`solve`); None if it was not abandoned.
    """

    def __init__(self, factory: Callable, start_timeout: float = 600.0, spare: bool = True):
        if multiprocessing.current_process().daemon:  # multiprocessing's own assertion said
            raise RuntimeError(DAEMON_REFUSED)  # only "daemonic processes are not allowed ..."
        self._ctx = multiprocessing.get_context("spawn")
        self.factory = factory
        self.start_timeout = start_timeout
        self.abandoned = 0
        self.last_error: str | None = None
        self.last_abandon: str | None = None
        self._dead: list[_Worker] = []  # killed workers not yet reaped
        self._active = self._started()
        self._spare = _Worker(factory, self._ctx, background=True) if spare else None

    def wait_spare(self, timeout: float) -> bool:
        """Wait until the spare worker is ready (tests, start-up); False without a spare."""
        return self._spare is not None and self._spare.wait_ready(timeout)

    def wait_active(self, timeout: float) -> bool:
        """Wait until the active worker is ready (after a replacement; without a spare, the
        successor is started here if no solve has started it yet)."""
        if self._active is None:
            self._active = _Worker(self.factory, self._ctx)
        return self._active.wait_ready(timeout)

    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0=None, lam_g0=None,
              max_iter: int | None = None, *, timeout: float, T_cap: float | None = None,
              cpu_timeout: float | None = None) -> SolveResult:  # fmt: skip
        """Solve in the worker (``max_iter``: the solver's iteration limit for this solve,
        None: its own; ``T_cap``: the planned thrust's cap, N, None: none) and abandon it:

        - field (``cpu_timeout`` None): after ``timeout`` s of wall time without an answer;
        - simulation's hang guard: once the worker has spent ``cpu_timeout`` s of CPU time
          (all its threads) on this solve, or has used no CPU for ``timeout`` s of this
          process's wall time (a stopped or blocked worker; a gap in which this process was
          stopped itself, e.g. the run suspended, counts as one poll, not as its length).
          A starved solve that still gets CPU is never abandoned.

        An abandoned worker is killed, the spare (or a new worker) takes over, and the result
        is a failure with status ``"deadline"`` and the warm start ``w0`` as its iterate (the
        next step starts warm from it); :attr:`last_abandon` says which limit it was.

        Raises
        ------
        RuntimeError
            Without a spare: the successor of a killed worker, started here, was not ready
            within ``start_timeout``."""
        if self._active is None:  # the successor of a worker killed without a spare (its
            self._active = self._started()  # start-up is not this solve's time)
        t0 = time.perf_counter()
        self.last_error = self.last_abandon = None
        for dead in self._dead:  # killed at an earlier deadline: gone by now
            dead.reap()
        self._dead.clear()
        w = self._active
        try:
            msg = (p, w0, lam_x0, lam_g0) + (() if max_iter is None else (max_iter,))
            if T_cap is not None:  # (sent only when set: the solver's call is as before)
                msg = (p, w0, lam_x0, lam_g0, max_iter, T_cap)
            # the idle worker's CPU time (read only for the hang guard: not on the field's path)
            cpu0 = cpu_s(w.proc) if cpu_timeout is not None and w.ready else math.nan
            w.conn.send(msg)
            if cpu_timeout is None:
                answer = self._wait_wall(w, timeout - (time.perf_counter() - t0))
            else:
                answer = self._wait_cpu(w, cpu0, cpu_timeout, timeout)
        except (EOFError, OSError):  # the worker died
            answer = ("error", "solver worker died")
        ms = (time.perf_counter() - t0) * 1e3
        if isinstance(answer, SolveResult):
            return SolveResult(answer.w, answer.lam_x, answer.lam_g, answer.f, answer.ok,
                               answer.status, answer.iters, ms)  # fmt: skip
        status = answer[1] if answer is not None else "deadline"
        self.last_error = None if answer is None else status  # the worker's exception
        self._replace()
        if answer is None:
            self.abandoned += 1
        return SolveResult(np.asarray(w0, float), None, None, math.nan, False, status, 0, ms)

    @staticmethod
    def _answer(w: _Worker):
        """The worker's next message, or None for the ready message of a promoted spare."""
        msg = w.conn.recv()
        if msg == _READY:  # a promoted spare that was still loading
            w.ready = True
            return None
        return msg

    def _wait_wall(self, w: _Worker, timeout: float):
        """The answer within ``timeout`` s of wall time, or None (``last_abandon`` "wall")."""
        t0 = time.perf_counter()
        while True:
            if not w.conn.poll(max(timeout - (time.perf_counter() - t0), 0.0)):
                self.last_abandon = "wall"
                return None
            answer = self._answer(w)
            if answer is not None:
                return answer

    def _wait_cpu(self, w: _Worker, cpu0: float, cpu_timeout: float, idle_timeout: float):
        """The answer before the worker spends ``cpu_timeout`` s of CPU on it (from ``cpu0``,
        NaN: not known yet) or uses none for ``idle_timeout`` s; else None
        (``last_abandon`` "cpu" or "idle")."""
        last, idle, t_prev = cpu0, 0.0, time.perf_counter()
        while True:
            if w.conn.poll(CPU_POLL_S):
                answer = self._answer(w)
                if answer is not None:
                    return answer
                cpu0 = last = cpu_s(w.proc)  # a spare ready only now: its loading not counted
                continue
            now = time.perf_counter()
            dt, t_prev = now - t_prev, now
            c = cpu_s(w.proc)
            if c - cpu0 > cpu_timeout:  # (NaN, unknown, never exceeds)
                if w.conn.poll(0):  # answered meanwhile: take it
                    continue
                self.last_abandon = "cpu"
                return None
            if math.isfinite(c) and not c <= last:  # progress (or the first known reading)
                last, idle = c, 0.0
            else:  # no CPU used: a longer gap than a poll means this process was stopped
                idle += min(dt, 2 * CPU_POLL_S)
            if idle > idle_timeout:
                self.last_abandon = "idle"
                return None

    def _started(self) -> _Worker:
        """A new worker, waited for until ready (RuntimeError, the worker killed, if it is
        not within ``start_timeout``)."""
        w = _Worker(self.factory, self._ctx)
        if not w.wait_ready(self.start_timeout):
            w.kill()
            raise RuntimeError(f"MPC solver worker not ready within {self.start_timeout:g} s")
        return w

    def _replace(self) -> None:
        """Kill the active worker (reaped at the next call); the spare takes over; a new spare
        starts in the background (the step's time is not spent on it). Without a spare: the
        successor is started by the next :meth:`solve` (none for a solver closed after it,
        e.g. a replay's)."""
        self._active.kill(wait=False)
        self._dead.append(self._active)
        if self._spare is None:
            self._active = None
            return
        self._active = self._spare
        self._spare = _Worker(self.factory, self._ctx, background=True, delay=SPARE_DELAY_S)

    def close(self) -> None:
        """Stop the workers."""
        for w in (self._active, self._spare):
            if w is not None:
                w.stop()
        for dead in self._dead:
            dead.reap()
        self._dead.clear()

    def __del__(self):  # pragma: no cover - best effort at interpreter exit
        try:
            self.close()
        except Exception:
            pass
