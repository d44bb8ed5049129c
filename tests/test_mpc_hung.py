"""A solve abandoned as hung is kept, written to the run folder and solved again
(``mpcasv/mpc/hung.py``, ``mpcasv replay-solve``; docs/mpc.md "Known problems").

The hang is injected (the real solver, except that one solve spins for ever, as fatrop's
inertia-correction loop does): a real fatrop hang depends on fatrop's build and is measured,
not tested (docs/mpc.md).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import pickle
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_io_bad_input import _exit_code, _refused
from test_mpc_deadline import spins

from mpcasv.controllers import make_controller
from mpcasv.mpc import hung
from mpcasv.mpc.controller import worker_solver
from mpcasv.sim.record import write_run
from mpcasv.sim.scenario import load_scenario, scenario_with
from mpcasv.sim.simulator import simulate

ROOT = Path(__file__).resolve().parents[1]

HANG_S = 1.0  # s of CPU time: the injected hang is abandoned after it


#: the injected hang: this solve of the worker's (1-based), when the flag file exists
HANG_CALL = 3


class _HangOnceRecording:
    """The real solver, except that its ``HANG_CALL``-th solve, if ``flag`` exists, pickles
    what it was sent (``flag``.sent) and never returns; the successor worker (the flag gone)
    solves normally."""

    def __init__(self, solver, flag: str):
        self.solver, self.flag, self.calls = solver, flag, 0

    def solve(self, *args):
        self.calls += 1
        if self.calls == HANG_CALL and os.path.exists(self.flag):
            os.remove(self.flag)
            with open(self.flag + ".sent", "wb") as f:
                pickle.dump(args, f)
            spins().solve()
        return self.solver.solve(*args)


def hang_once_recording(flag: str, params, n_auv: int, multi: bool):
    return _HangOnceRecording(worker_solver(params, n_auv, multi, None), flag)


@pytest.fixture(scope="module")
def hung_run(tmp_path_factory):
    """3 s of Case 3 with mpc-single under the simulation's hang guard, its first solve hanging:
    (controller, run result, what the hung solve was sent)."""
    flag = tmp_path_factory.mktemp("hang") / "hang"
    sc = scenario_with(load_scenario(ROOT / "experiments" / "scenarios" / "case3.toml"),
                       duration=3.0)  # fmt: skip
    c = make_controller("mpc-single", 1, "mpc-single", overrides={"solver.hang_s": HANG_S})

    def guard():  # use_hang_guard, with the hanging solver
        c.use_deadline(functools.partial(hang_once_recording, str(flag), c.params, 1, False),
                       spare=False)  # fmt: skip
        c._hang_guard = True

    c.use_hang_guard = guard
    flag.touch()
    res = simulate(sc, c, seed=0)
    assert not flag.exists()  # the worker did start the hanging solve
    with open(str(flag) + ".sent", "rb") as f:
        return c, res, pickle.load(f)


def test_a_hung_solve_is_kept_with_what_the_worker_was_sent(hung_run):
    c, res, sent = hung_run
    assert res.timeseries["mpc_hung"].sum() == 1 and len(res.hung_solves) == 1
    s = res.hung_solves[0]
    assert s.n_auv == 1 and not s.multi and s.cpu_s == HANG_S
    ts = res.timeseries  # a row's t is the end of its 1-s period: the step began 1 s before
    assert s.t == ts.loc[ts["mpc_hung"] == 1, "t"].iloc[0] - 1.0 > 0.0
    assert s.params == c.params and s.boat is c.boat
    p, w0, lam_x, lam_g, *rest = sent
    assert lam_x is not None and lam_g is not None  # warm multipliers: all fields are tested
    assert all(np.array_equal(a, b) for a, b in ((s.p, p), (s.w0, w0), (s.lam_x, lam_x),
                                                 (s.lam_g, lam_g)))  # fmt: skip
    assert (s.max_iter, s.T_cap) == ((rest + [None, None])[0], (rest + [None, None])[1])
    assert s.p.shape == (c.ocp.nlp["p"].numel(),) and s.w0.shape == (c.ocp.nlp["x"].numel(),)


def test_a_replay_solves_the_very_problem_that_hung(hung_run):
    """The replay (a fresh worker process, the real solver) returns what this process's solver
    returns on the recorded problem: the same cost and iterations, so the record is the
    problem that was sent, not an approximation of it."""
    c, res, _ = hung_run
    (s,) = res.hung_solves
    r = hung.replay(s)
    cap = {} if s.T_cap is None else {"T_cap": s.T_cap}
    here = c.solver.solve(s.p, s.w0, s.lam_x, s.lam_g, s.max_iter, **cap)
    assert not r.hung
    assert (r.f, r.iters, r.ok, r.status) == (here.f, here.iters, here.ok, here.status)


def test_fatrop_makes_one_iteration_more_than_its_limit_and_says_so(hung_run):
    """``replay-solve --max-iter 3`` says "4 iterations": that is fatrop's own count, not ours
    (docs/mpc.md "Solvers and speed"). fatrop (1.1.8, CasADi 3.8) tests its limit against the
    count before the step it has just made, so it stops after K + 1 steps and reports K + 1
    (its log's rows 1..K + 1); IPOPT, on the same problem, stops after K. We pass the
    solver's ``iter_count`` through unchanged."""
    import dataclasses as dc

    from mpcasv.mpc.solvers import NLPSolver

    c, res, _ = hung_run
    (s,) = res.hung_solves
    cap = {} if s.T_cap is None else {"T_cap": s.T_cap}
    for k in (1, 2, 3):  # this problem needs more: each solve stops at its limit (status 1)
        r = c.solver.solve(s.p, s.w0, s.lam_x, s.lam_g, k, **cap)
        assert (r.ok, r.status, r.iters) == (False, "1", k + 1), k
        assert c.solver.last_stats["iter_count"] == k + 1
    ipopt = NLPSolver(c.ocp, dc.replace(c.params.solver, solver="ipopt", compiled=False),
                      log=lambda *a: None)  # fmt: skip
    r = ipopt.solve(s.p, s.w0, s.lam_x, s.lam_g, 3, **cap)
    assert (r.ok, r.status, r.iters) == (False, "Maximum_Iterations_Exceeded", 3)


def test_a_replay_that_hangs_again_is_abandoned_on_its_cpu_time(hung_run):
    (s,) = hung_run[1].hung_solves
    r = hung.replay(s, cpu_s=0.5, factory=spins)
    assert r.hung and r.by_cpu and r.status == "deadline" and r.wall_s < 30.0


def test_the_run_folder_keeps_the_hung_solves_and_the_command_replays_them(
        hung_run, tmp_path, capsys):  # fmt: skip
    res = hung_run[1]
    write_run(res, tmp_path / "run", {}, plots=False)
    f = tmp_path / "run" / hung.FILE_NAME
    assert [x.t for x in hung.load(f)] == [s.t for s in res.hung_solves]
    assert _exit_code(["replay-solve", f, "--max-iter", "3"]) == 0
    out = capsys.readouterr().out
    assert "max_iter 3: returned" in out and "0 of 1 hung again" in out
    # a run without hangs writes no file
    write_run(dataclasses.replace(res, hung_solves=[]), tmp_path / "run2", {}, plots=False)
    assert not (tmp_path / "run2" / hung.FILE_NAME).exists()


def test_a_record_keeps_its_problems_digest_and_a_replay_names_another_problem(
        hung_run, tmp_path, capsys):  # fmt: skip
    """The record's digest is the problem's (the same problem rebuilt here: no note); a record
    whose digest differs (another version's equations with the same sizes: session 32's guard
    changed the dynamics, not the sizes) or that has none (written before) is named before its
    replay, which still runs."""
    c, res, _ = hung_run
    (s,) = res.hung_solves
    assert s.problem == hung.problem_digest(c.ocp) and hung.same_problem(s) is True
    other = dataclasses.replace(s, problem="0" * 16)
    old = dataclasses.replace(s, problem="")
    assert hung.same_problem(other) is False and hung.same_problem(old) is None
    for rec, words in ((s, None), (other, "is not the one that hung"),
                       (old, "without the problem's digest")):  # fmt: skip
        f = tmp_path / "hung.pkl"
        f.write_bytes(pickle.dumps([rec]))
        assert _exit_code(["replay-solve", f, "--max-iter", "3"]) == 0
        out = capsys.readouterr().out
        assert "0 of 1 hung again" in out
        assert ("note:" in out) == (words is not None) and (words is None or words in out)


def test_a_qp_replay_says_feasible_not_converged(hung_run, tmp_path, capsys):
    """The QP variant's ``ok`` is a feasible plan, not convergence, and its work is bounded by
    ``qp_iters`` (no iteration limit): the replay's line says so (it said "converged (status
    max_iter)" under "max_iter 50"). Five steps: since the integral terminal (M7i, session
    39) one to three SQP steps from this warm start end infeasible (0.082, 0.034, 0.0018)."""
    f = tmp_path / hung.FILE_NAME
    f.write_bytes(pickle.dumps(hung_run[1].hung_solves))
    assert _exit_code(["replay-solve", f, "--set", "solver.solver='qp'",
                       "--set", "solver.qp_iters=5"]) == 0  # fmt: skip
    (line,) = [x for x in capsys.readouterr().out.splitlines() if x.startswith("[0]")]
    assert ", qp, qp_iters 5: returned" in line and "max_iter 50" not in line
    assert "feasible, not converged (status max_iter: its qp_iters steps made), 5 steps," in line
    _refused(["replay-solve", f, "--set", "solver.solver='qp'", "--max-iter", "3"], capsys,
             "--max-iter", "qp_iters")  # fmt: skip


def test_replay_solve_refuses_bad_input_in_one_line(hung_run, tmp_path, capsys):
    solves = hung_run[1].hung_solves
    good = tmp_path / "good.pkl"
    good.write_bytes(pickle.dumps(solves))

    def pkl(name: str, obj=None, raw: bytes | None = None) -> Path:
        f = tmp_path / name
        f.write_bytes(pickle.dumps(obj) if raw is None else raw)
        return f

    for f in (pkl("garbage.pkl", raw=b"not a pickle at all"), pkl("other.pkl", {"a": 1}),
              pkl("huge.pkl", raw=b"\x80\x05\x8e" + b"\xff" * 8),  # a vast byte string
              pkl("cut.pkl", raw=good.read_bytes()[:100])):  # fmt: skip
        _refused(["replay-solve", f], capsys, str(f), "not a file of hung solves")
    f = pkl("bad_params.pkl", [dataclasses.replace(solves[0], params="notparams")])
    _refused(["replay-solve", f], capsys, str(f), "malformed", "MPCParams")
    f = pkl("bad_p.pkl", [dataclasses.replace(solves[0], p=[1.0, 2.0])])
    _refused(["replay-solve", f], capsys, str(f), "malformed", "p is not")
    _refused(["replay-solve", pkl("empty.pkl", [])], capsys, "holds no hung solves")
    _refused(["replay-solve", tmp_path / "none.pkl"], capsys, "none.pkl")
    _refused(["replay-solve", good, "--index", "1"], capsys, "--index 1", "holds 1 hung solve")
    _refused(["replay-solve", good, "--set", "solver.nope=1"], capsys, "solver.nope")
    _refused(["replay-solve", good, "--set", "solver.tol=-3"], capsys, "--set", "tol")
    _refused(["replay-solve", good, "--set", "solver.max_iter=30"], capsys, "--max-iter")
    _refused(["replay-solve", good, "--set", "solver.hang_s=1"], capsys, "--cpu-s")
    _refused(["replay-solve", good, "--set", "solver.budget_ms=5"], capsys, "budget_ms",
             "reach the solver")  # fmt: skip
    _refused(["replay-solve", good, "--set", "max_iter=3"], capsys, "solver.KEY=VALUE")
    for v in ("0", "-1", "inf", "nan"):
        _refused(["replay-solve", good, "--cpu-s", v], capsys, "--cpu-s")
    _refused(["replay-solve", good, "--max-iter", str(2**31)], capsys, "--max-iter")


def test_a_solve_that_fails_in_the_worker_is_an_error_not_a_result(hung_run, tmp_path,
                                                                   capsys):  # fmt: skip
    """Parameters of another size than the problem's (a record of another version): the
    worker's exception is one line and exit 2, not a "returned, not converged" result."""
    s = hung_run[1].hung_solves[0]
    f = tmp_path / "short.pkl"
    f.write_bytes(pickle.dumps([dataclasses.replace(s, p=s.p[:-3])]))
    line = _refused(["replay-solve", f, "--cpu-s", "5"], capsys, "[0]", "failed in the worker")
    assert "p" in line


def test_an_exported_solve_runs_without_mpcasv_and_solves_as_the_uncompiled_solver(
        hung_run, tmp_path, capsys):  # fmt: skip
    """``replay-solve --export``: the folder's reproduce.py, run where ``import mpcasv`` fails,
    returns the iterations and cost, bit for bit, of this process's uncompiled solver (CasADi's
    own derivatives, the problem the export holds) on the recorded solve: as recorded (no
    thrust cap, the preset's iteration limit; at a lower limit too), and with a binding thrust
    cap and an iteration limit of its own, with fatrop and with IPOPT (the dual start), so the
    export is the very problem, its bounds, start and options."""
    c, res, _ = hung_run
    (s,) = res.hung_solves
    capped = dataclasses.replace(s, T_cap=0.2 * c.ocp.vessel.T_max, max_iter=2)  # converges in 3
    f = tmp_path / hung.FILE_NAME
    f.write_bytes(pickle.dumps([s, capped]))
    assert _exit_code(["replay-solve", f, "--export", tmp_path / "exp"]) == 0
    assert str(tmp_path / "exp" / "solve-1") in capsys.readouterr().out
    assert {p.name for p in (tmp_path / "exp" / "solve-0").iterdir()} == {
        "nlp.casadi", "problem.npz", "options.json", "reproduce.py", "README.md"}
    poison = tmp_path / "poison" / "mpcasv"
    poison.mkdir(parents=True)
    (poison / "__init__.py").write_text("raise ImportError('mpcasv imported')\n")
    env = os.environ | {"PYTHONPATH": str(poison.parent)}
    here_solvers, results = {}, {}
    for k, rec, solver, limit in ((0, s, "fatrop", 2), (0, s, "fatrop", None),  # fmt: skip
                                  (1, capped, "fatrop", None), (1, capped, "ipopt", None)):
        out = subprocess.run([sys.executable, "reproduce.py", "--solver", solver]
                             + ([] if limit is None else ["--max-iter", str(limit)]),
                             cwd=tmp_path / "exp" / f"solve-{k}", env=env, capture_output=True,
                             text=True, timeout=300, check=True).stdout  # fmt: skip
        m = re.search(r"iterations (\d+), cost (\S+)", out)
        assert m, out
        if solver not in here_solvers:
            u = hung.with_solver(s, {"compiled": False, "solver": solver})
            here_solvers[solver] = worker_solver(u.params, u.n_auv, u.multi, u.boat)
        cap = {} if rec.T_cap is None else {"T_cap": rec.T_cap}
        here = here_solvers[solver].solve(rec.p, rec.w0, rec.lam_x, rec.lam_g,
                                          rec.max_iter if limit is None else limit, **cap)
        assert (int(m[1]), float(m[2])) == (here.iters, here.f), (k, solver, limit)
        results[k, solver, limit] = here.f
    assert results[1, "fatrop", None] != results[0, "fatrop", 2]  # the cap binds
    # other settings than the record's: in the options, and named in the README
    assert _exit_code(["replay-solve", f, "--index", "0", "--export", tmp_path / "tol",
                       "--set", "solver.tol=0.5"]) == 0  # fmt: skip
    opts = json.loads((tmp_path / "tol" / "solve-0" / "options.json").read_text())
    assert opts["fatrop"]["fatrop.tol"] == 0.5 and opts["ipopt"]["ipopt.tol"] == 0.5
    readme = (tmp_path / "tol" / "solve-0" / "README.md").read_text()
    assert f"`tol` = 0.5 (recorded: {s.params.solver.tol!r})" in readme
    assert f"hung with fatrop (max_iter\n{s.params.solver.max_iter}" in readme


def test_export_refuses_what_it_cannot_write_in_one_line(hung_run, tmp_path, capsys):
    solves = hung_run[1].hung_solves
    good = tmp_path / "good.pkl"
    good.write_bytes(pickle.dumps(solves))
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    _refused(["replay-solve", good, "--export", a_file], capsys, "--export", str(a_file),
             "a file is there")  # fmt: skip
    _refused(["replay-solve", good, "--export", tmp_path / "e", "--max-iter", "3"], capsys,
             "--export", "reproduce.py")  # fmt: skip
    _refused(["replay-solve", good, "--export", tmp_path / "e", "--set", "solver.solver='qp'"],
             capsys, "[0]", "qp", "NLP")  # fmt: skip
    _refused(["replay-solve", good, "--export", tmp_path / "e", "--set",
              "solver.compiled=false"], capsys, "solver.compiled", "does not apply")  # fmt: skip
    _refused(["replay-solve", good, "--export", ""], capsys, "--export", "empty folder")
    (tmp_path / "d" / "solve-0" / "nlp.casadi").mkdir(parents=True)  # cannot be a file
    _refused(["replay-solve", good, "--export", tmp_path / "d"], capsys, "nlp.casadi",
             "cannot be written")  # fmt: skip
    short = tmp_path / "short.pkl"
    short.write_bytes(pickle.dumps([dataclasses.replace(solves[0], p=solves[0].p[:-3])]))
    _refused(["replay-solve", short, "--export", tmp_path / "e"], capsys, "[0]", "another version")
