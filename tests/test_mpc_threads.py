"""``solver.threads``: the horizon's stages evaluated by an OpenMP loop in the compiled library.

The whole MPC library takes 40-60 s to compile, so the mechanism is tested on a small
function through the same code generation and compiler path; that the full solves are the
same bit for bit with 1 and 2 threads is measured by ``mpcasv bench mpc --threads 2``
(docs/mpc.md, "Benchmark").
"""

from __future__ import annotations

import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest

from mpcasv.config import ConfigError, parse
from mpcasv.controllers import load_preset
from mpcasv.mpc.codegen import (
    compiled_library,
    thread_cflags,
    with_thread_count,
    write_source,
)
from mpcasv.mpc.derivatives import _over_horizon, nlp_functions
from mpcasv.mpc.problem import OCP
from mpcasv.mpc.solver_params import SolverParams


def test_thread_flags_add_openmp_and_the_thread_count_only_above_one():
    assert thread_cflags("-O3 -march=native", 1) == "-O3 -march=native"
    flags = thread_cflags("-O3", 2)
    assert "-fopenmp" in flags and "-DMPCASV_THREADS=2" in flags


def test_threads_need_a_compiled_nlp_solver():
    with pytest.raises(ConfigError, match="threads > 1 needs compiled"):
        parse(SolverParams, {"threads": 2, "compiled": False})
    with pytest.raises(ConfigError, match="threads > 1 needs compiled"):
        parse(SolverParams, {"threads": 2, "solver": "qp"})
    with pytest.raises(ConfigError):
        parse(SolverParams, {"threads": 0})
    assert parse(SolverParams, {"threads": 2}).threads == 2


def test_openmp_maps_are_the_same_functions_as_the_loops():
    """``nlp_functions(..., threads=2)`` holds OpenMP maps that evaluate (in CasADi's own,
    serial, evaluation) exactly like the plain loops."""
    ocp = OCP(load_preset("mpc-single", "mpc-single"), 1, outer=True)
    serial, parallel = nlp_functions(ocp, "fatrop"), nlp_functions(ocp, "fatrop", threads=2)
    for funs, loops in ((serial, 0), (parallel, 4)):  # f and g, gradient, Jacobian, Hessian
        gen = ca.CodeGenerator("nlp.c")
        for name in ("nlp_hess_l", "nlp_jac_g", "nlp_grad_f", "nlp"):
            gen.add(funs[name])
        assert gen.dump().count("#pragma omp parallel for") == loops
    rng = np.random.default_rng(0)
    x = ocp.scaled(ocp.rollout(_params(ocp))) + 1e-3 * rng.standard_normal(ocp.dims.nw)
    args = [x, _params(ocp), 1.0, rng.standard_normal(ocp.dims.ng)]
    for name in ("nlp_hess_l", "nlp_jac_g", "nlp_grad_f", "nlp_g"):
        n_in = serial[name].n_in()
        a = [np.asarray(o) for o in ca.Function.call(serial[name], args[:n_in])]
        b = [np.asarray(o) for o in ca.Function.call(parallel[name], args[:n_in])]
        for u, v in zip(a, b, strict=True):
            np.testing.assert_array_equal(u, v)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler (gcc) on this machine")
def test_compiled_openmp_loop_has_its_thread_count_and_gives_the_serial_results(tmp_path,
                                                                                monkeypatch):
    """Through the library cache's own generator and compiler: the generated OpenMP loop is
    given ``num_threads`` from the flags, compiles, and returns what the plain loop does."""
    monkeypatch.setenv("MPCASV_CACHE", str(tmp_path))
    z = ca.SX.sym("z", 4)
    f = ca.Function("stage", [z], [ca.vertcat(ca.sin(z[0]) * z[1], ca.exp(z[2]) - z[3])])
    Z = ca.MX.sym("Z", 4, 15)
    funs = {t: {"g": ca.Function("g", [Z], [_over_horizon(f, 15, t)(Z)])} for t in (1, 2)}
    libs = {t: compiled_library(funs[t], "test", thread_cflags("-O2", t), log=lambda _: None)
            for t in (1, 2)}  # fmt: skip
    assert libs[1] != libs[2]  # the flags are part of the key
    if shutil.which("nm"):  # the library built by the cache's own compile runs OpenMP loops
        syms = {t: subprocess.run(["nm", "-D", str(libs[t])], capture_output=True, text=True,
                                  check=True).stdout for t in (1, 2)}  # fmt: skip
        assert "GOMP_parallel" in syms[2] and "GOMP_parallel" not in syms[1]
    # the source the cache compiles: the loop with its thread count (only with the flag)
    src = {t: write_source(funs[t], tmp_path / f"g{t}.c", thread_cflags("-O2", t)).read_text()
           for t in (1, 2)}  # fmt: skip
    assert src[2].count("#pragma omp parallel for num_threads(MPCASV_THREADS)") == 1
    assert "#pragma omp" not in src[1]
    assert with_thread_count(src[2], "-O2") == src[2]
    Zv = np.random.default_rng(1).standard_normal((4, 15))
    out = {t: np.asarray(ca.external("g", str(libs[t]))(Zv)) for t in (1, 2)}
    np.testing.assert_array_equal(out[1], out[2])
    np.testing.assert_allclose(out[1], np.asarray(funs[1]["g"](Zv)), rtol=1e-15, atol=0)


def _params(ocp: OCP) -> np.ndarray:
    from test_mpc_problem import params_for

    return params_for(ocp)
