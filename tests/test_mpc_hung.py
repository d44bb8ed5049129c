"""A solve abandoned as hung is kept, written to the run folder and solved again
(``mpcasv/mpc/hung.py``, ``mpcasv replay-solve``; docs/mpc.md "Known problems").

The hang is injected (the real solver, except that one solve spins for ever, as fatrop's
inertia-correction loop does): a real fatrop hang depends on fatrop's build and is measured,
not tested (docs/mpc.md).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import pickle
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


class _HangOnceRecording:
    """The real solver, except that the first solve after ``flag`` appears saves what it was
    sent (``flag``.npz) and never returns."""

    def __init__(self, solver, flag: str):
        self.solver, self.flag = solver, flag

    def solve(self, p, w0, *args):
        if os.path.exists(self.flag):
            os.remove(self.flag)
            np.savez(self.flag + ".npz", p=p, w0=w0)
            spins().solve()
        return self.solver.solve(p, w0, *args)


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
    return c, res, dict(np.load(str(flag) + ".npz"))


def test_a_hung_solve_is_kept_with_what_the_worker_was_sent(hung_run):
    c, res, sent = hung_run
    assert res.timeseries["mpc_hung"].sum() == 1 and len(res.hung_solves) == 1
    s = res.hung_solves[0]
    assert s.t == 0.0 and s.n_auv == 1 and not s.multi and s.cpu_s == HANG_S
    assert s.params == c.params and s.boat is c.boat
    assert np.array_equal(s.p, sent["p"]) and np.array_equal(s.w0, sent["w0"])
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


def test_a_replay_that_hangs_again_is_abandoned_on_its_cpu_time(hung_run):
    (s,) = hung_run[1].hung_solves
    r = hung.replay(s, cpu_s=0.5, factory=spins)
    assert r.hung and r.status == "deadline" and r.wall_s < 20 * 0.5


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


def test_replay_solve_refuses_bad_input_in_one_line(hung_run, tmp_path, capsys):
    solves = hung_run[1].hung_solves
    good = tmp_path / "good.pkl"
    hung.save(solves, good)
    garbage = tmp_path / "garbage.pkl"
    garbage.write_bytes(b"not a pickle at all")
    other = tmp_path / "other.pkl"
    other.write_bytes(pickle.dumps({"a": 1}))
    _refused(["replay-solve", garbage], capsys, str(garbage), "not a file of hung solves")
    _refused(["replay-solve", other], capsys, str(other), "not a file of hung solves")
    _refused(["replay-solve", tmp_path / "none.pkl"], capsys, "none.pkl")
    _refused(["replay-solve", good, "--index", "1"], capsys, "--index 1", "holds 1 solves")
    _refused(["replay-solve", good, "--set", "solver.nope=1"], capsys, "solver.nope")
    _refused(["replay-solve", good, "--set", "solver.max_iter=-3"], capsys, "--set")
    _refused(["replay-solve", good, "--set", "max_iter=3"], capsys, "solver.KEY=VALUE")
    _refused(["replay-solve", good, "--cpu-s", "0"], capsys, "--cpu-s")
