"""Tests of identification (mpcasv.models.identify) and the simulator manoeuvres."""

from __future__ import annotations

import math

import imcpy
import numpy as np
import pandas as pd
import pytest
from shared_data import DATA

from mpcasv.cli import main
from mpcasv.control.manoeuvres import Noise, simulate_manoeuvre
from mpcasv.io.identlog import load_log
from mpcasv.io.lsf import LogError
from mpcasv.models.ident_cov import (
    METHOD,
    SHAKY,
    bartlett_lrv,
    sigma_uncertainty,
    uncertain_sigma_note,
    window_covariance,
)
from mpcasv.models.ident_output import report_table, write_params
from mpcasv.models.ident_table import REQUIRED
from mpcasv.models.identify import (
    DAMPING,
    IDENTIFIED,
    OUTPUTS,
    Problem,
    fit_metrics,
    identify,
    mass_terms,
    prepare,
)  # fmt: skip
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import VesselModel

SHARED_LOG = DATA / "dune-lauv-followref.lsf.gz"
CURRENT = (0.2, -0.1)
PLAN = (("zigzag", 1.5, 20, 150), ("zigzag", 2.2, 20, 150), ("turning-circle", 2.0, 30, 150),
        ("turning-circle", 1.0, 20, 150), ("speed-steps", 1.5, 20, 240))  # fmt: skip


@pytest.fixture(scope="module")
def prior():
    return load_vessel("gretha")


@pytest.fixture(scope="module")
def case(prior):
    """Truth = prior with every identified coefficient scaled by a random factor in [0.7, 1.3];
    noisy simulator manoeuvres in a current; identification from the prior."""
    rng = np.random.default_rng(5)
    truth = prior.with_coeffs(**{c: getattr(prior, c) * rng.uniform(0.7, 1.3) for c in IDENTIFIED})
    model = VesselModel(truth)
    logs = [simulate_manoeuvre(model, name, u0=u, delta_deg=d, duration=T, current=CURRENT,
                               noise=Noise(), seed=10 + i)
            for i, (name, u, d, T) in enumerate(PLAN)]  # fmt: skip
    return truth, identify(logs, prior)


def test_identification_recovers_perturbed_model(prior, case):
    truth, res = case
    assert max(abs(getattr(truth, c) / getattr(prior, c) - 1) for c in IDENTIFIED) > 0.15
    mt, mi = mass_terms(truth), mass_terms(res.params)
    for k in mt:
        assert mi[k] == pytest.approx(mt[k], rel=0.10), k
    for c in DAMPING:
        assert getattr(res.params, c) == pytest.approx(getattr(truth, c), rel=0.20), c
    assert res.current == pytest.approx(CURRENT, abs=0.03)
    # validation error is reported, and the identified model replays held-out data better
    for c in OUTPUTS:
        val = res.metrics["simulation_error"]["validation"][c]
        assert np.isfinite(val["rmse"]) and val["fit_pct"] > res.metrics["prior"]["validation"][
            c]["fit_pct"]  # fmt: skip
    assert res.metrics["simulation_error"]["validation"]["r"]["fit_pct"] > 80


def test_identified_params_file_loads(prior, case, tmp_path):
    _, res = case
    path = tmp_path / "id.toml"
    write_params(path, res, prior, ["a.csv"])
    p = load_vessel(path)  # strict loading: provenance for every number
    assert p.vector() == pytest.approx(res.params.vector())
    assert "identified by mpcasv identify from a.csv" in p.provenance["N_rdot"]
    assert "Newey-West HAC" in p.provenance["N_rdot"] and "variance" in p.provenance["N_rdot"]
    assert f"# 1-sigma: {METHOD}." in path.read_text()
    assert p.provenance["Y_v"].startswith("held at the prior")


def test_noise_free_log_replays_exactly_and_identifies_the_truth(tmp_path, prior):
    """The documented workflow on a noise-free zig-zag of the prior (default 150 s, written
    and read as the CLI does): the set-points are held as logged, the prior (the truth)
    replays the log at ~100 % and, from a prior 20 % off, the truth is recovered.

    The CSV's time column is rounded, so the resampling grid ``k * median(dt)`` fell ~4e-16 s
    short of the logged times (any CSV log of 137 s or more at 0.1 s) and the set-point hold
    took the row before: every steering switch came one step late (prior psi fit 95.8 %,
    identified N_rdot -28 %, X_u -80 %). Tolerance 1 %: model and integrator are the
    simulator's, so what is left is the CSV's 6 significant digits and the solver's stopping
    rule (measured: all within 0.004 %)."""
    path = tmp_path / "zz.csv"
    assert main(["simulate", "--manoeuvre", "zigzag", "--out", str(path), "--quiet"]) == 0
    table = load_log(path, prior)
    logged = pd.read_csv(path)
    for c in ("T_cmd", "delta_cmd"):
        assert np.array_equal(table[c].to_numpy(), logged[c].to_numpy()), c
    prob = Problem(prior)
    _, info = prob.replay([prepare(table, prior)], 30.0)
    fits = fit_metrics(np.array(info["replay"](np.r_[prob.theta0(), np.zeros(info["n_x0"])])),
                       info["Y"])  # fmt: skip
    assert min(f["fit_pct"] for f in fits.values()) > 99.0, fits
    off = prior.with_coeffs(**{c: 1.2 * getattr(prior, c) for c in IDENTIFIED})
    res = identify([table], off)
    for split in ("train", "validation"):
        fits = res.metrics["simulation_error"][split]
        assert min(f["fit_pct"] for f in fits.values()) > 99.0, (split, fits)
    for c in IDENTIFIED:
        assert getattr(res.params, c) == pytest.approx(getattr(prior, c), rel=0.01), c
        assert res.rel_std[c] < 0.001, (c, res.rel_std[c])  # HAC 1-sigma: measured <= 0.007 %
    assert res.current == pytest.approx((0.0, 0.0), abs=1e-3)
    assert "serially correlated" not in report_table(res, prior)
    assert "itself uncertain" not in report_table(res, prior)


def _ar1(rng, shape, rho):
    x = np.empty(shape)
    z = rng.normal(size=shape)
    x[..., 0] = z[..., 0] / math.sqrt(1 - rho**2)
    for t in range(1, shape[-1]):
        x[..., t] = rho * x[..., t - 1] + z[..., t]
    return x


@pytest.mark.parametrize("L", [1, 10, 60])
def test_sigma_uncertainty_is_the_spread_of_the_bartlett_estimate(L):
    """Monte Carlo (seeded): the relative standard deviation of a Bartlett long-run variance
    with lag L (bandwidth L + 1) over n white samples is sqrt(4 (L + 1) / (3 n)), of its
    square root half that (Andrews 1991, Prop. 1(b)): what ``sigma_rel_sd`` quotes. At L = 1
    the bandwidth matters: sqrt(L / 3n) would be 30 % low."""
    rng = np.random.default_rng(7)
    W, nwin = 300, 3
    sig = [math.sqrt(bartlett_lrv(rng.normal(size=(nwin, W)), L)) for _ in range(600)]
    spread = np.std(sig) / np.mean(sig)
    assert spread == pytest.approx(float(sigma_uncertainty(L, W * nwin)), rel=0.15)
    assert float(sigma_uncertainty(L, W * nwin)) == pytest.approx(math.sqrt((L + 1) / 2700))


def test_the_uncertain_sigma_note_names_the_coefficients_above_the_limit():
    shaky = {"X_u": 0.05, "N_r": SHAKY + 0.01, "I_z": 0.3}
    note = uncertain_sigma_note(shaky, "this log")
    assert "(N_r, I_z)" in note and "about 30 %" in note and "samples of this log" in note
    assert "every coefficient" in uncertain_sigma_note({"X_u": 0.3, "N_r": 0.25})
    assert uncertain_sigma_note({"X_u": SHAKY, "N_r": 0.0}) is None


def test_hac_sigma_is_the_sampling_sigma_for_ar1_errors():
    """Monte Carlo (seeded, ~1 s): a linear regression whose errors and regressor are AR(1)
    (rho = phi = 0.8) in 5 independent windows of 200 samples. The slope's sampling sigma is
    about sqrt((1 + rho phi) / (1 - rho phi)) = 2.1 times the independent-residual one: the
    HAC sigma is within 15 % of the observed spread, the plain one half of it. White errors:
    both agree."""
    rng = np.random.default_rng(1)
    W, nwin, R = 200, 5, 300
    x = _ar1(rng, (nwin, W), 0.8).ravel()  # fixed design
    J = np.column_stack([np.ones(W * nwin), x])
    for rho, hac_vs_true, plain_vs_true in ((0.8, (0.85, 1.15), (0.35, 0.6)),
                                            (0.0, (0.85, 1.15), (0.85, 1.15))):  # fmt: skip
        slope, s_hac, s_plain = [], [], []
        for _ in range(R):
            e = _ar1(rng, (nwin, W), rho).ravel()
            y = 1.0 + 2.0 * x + e
            b = np.linalg.lstsq(J, y, rcond=None)[0]
            cov = window_covariance(J, y - J @ b, W, nwin, cols=[1])
            slope.append(b[1])
            s_hac.append(math.sqrt(cov.hac[0]))
            s_plain.append(math.sqrt(cov.plain[0]))
        true = float(np.std(slope))
        assert hac_vs_true[0] < np.median(s_hac) / true < hac_vs_true[1], rho
        assert plain_vs_true[0] < np.median(s_plain) / true < plain_vs_true[1], rho


def test_hac_reads_the_replay_layout():
    """Residuals as ``Problem.replay`` lays them out (``ca.vec`` of channels x samples: each
    sample's channels together, windows one after the other): smooth residuals in one channel
    widen only the coefficient that channel determines (one global factor from the worst
    channel widened both)."""
    rng = np.random.default_rng(2)
    W, nwin, k = 100, 4, 2
    E = np.empty((k, W * nwin))
    E[0] = _ar1(rng, (nwin, W), 0.95).ravel() * math.sqrt(1 - 0.95**2)  # smooth, variance 1
    E[1] = rng.normal(size=W * nwin)  # channel 1: white
    J = np.zeros((k, W * nwin, 2))
    J[0, :, 0] = _ar1(rng, (nwin, W), 0.95).ravel()  # parameter 0 seen by channel 0 only
    J[1, :, 1] = _ar1(rng, (nwin, W), 0.95).ravel()  # parameter 1 by channel 1 only
    res = E.ravel(order="F")  # ca.vec: column-major
    Jv = J.transpose(1, 0, 2).reshape(-1, 2)
    cov = window_covariance(Jv, res, W, nwin)
    assert cov.ratio[0] > 4 and 0.5 < cov.ratio[1] < 2, cov.ratio


@pytest.fixture(scope="module")
def zigzag(tmp_path_factory, prior):
    """The default noise-free zig-zag as the CLI writes and reads it."""
    path = tmp_path_factory.mktemp("zz") / "zz.csv"
    assert main(["simulate", "--manoeuvre", "zigzag", "--out", str(path), "--quiet"]) == 0
    return load_log(path, prior)


def test_identify_cli_records_the_sigma_basis(zigzag, tmp_path):
    """identify.json records the 1-sigma method, the plain figures and the variance ratio."""
    import json

    log = tmp_path / "zz.csv"
    zigzag.to_csv(log, index=False)
    out = tmp_path / "p.toml"
    assert main(["identify", str(log), "--out", str(out), "--quiet"]) == 0
    rec = json.loads((tmp_path / "p-report" / "identify.json").read_text())
    assert rec["sigma_method"] == METHOD
    assert set(rec["var_ratio"]) == set(rec["rel_std"]) == set(rec["rel_std_plain"]) == set(
        rec["sigma_rel_sd"])
    assert "1-sigma: Newey-West" in (tmp_path / "p-report" / "identify.md").read_text()


def test_quoted_sigma_covers_the_error_of_a_late_set_point(zigzag, prior):
    """End to end through ``identify()``: the noise-free zig-zag with one steering switch (the
    fourth, 37.5 s) logged a step late, a model error of the kind the old resampling bug made.
    The fit misses the truth by up to 76 % (X_udot at its bound) and the residuals are smooth:
    the HAC 1-sigma covers every error within 2 sigma (measured: within 0.6), the
    independent-residual one does not (N_rdot -20.5 % against 5.4 %), and the report warns."""
    table = zigzag.copy()
    d = table["delta_cmd"].to_numpy().copy()
    k = np.flatnonzero(np.diff(d) != 0)[3] + 1
    d[k] = d[k - 1]
    table["delta_cmd"] = d
    off = prior.with_coeffs(**{c: 1.2 * getattr(prior, c) for c in IDENTIFIED})
    res = identify([table], off)
    assert res.sigma_method == METHOD
    err = {c: abs(getattr(res.params, c) / getattr(prior, c) - 1) for c in IDENTIFIED}
    assert max(err.values()) > 0.1  # the set-point did spoil the fit
    for c in IDENTIFIED:
        assert err[c] < 2 * res.rel_std[c], (c, err[c], res.rel_std[c])
    assert any(err[c] > 2 * res.rel_std_plain[c] for c in IDENTIFIED)
    assert min(res.var_ratio.values()) > 4
    table_md = report_table(res, prior)
    assert "serially correlated" in table_md and "filtered" in table_md
    # three training windows and a lag as long as a window: the 1-sigma is itself shaky
    assert min(res.sigma_rel_sd.values()) > 0.2
    assert "1-sigma is itself uncertain (every coefficient)" in table_md
    # ... and says from which lag and how many samples (session 26: it gave neither)
    assert f"n = {res.sigma_n:,} samples in replay windows" in table_md and "lag L = " in table_md


def test_manoeuvre_cli_writes_seeded_logs(tmp_path, prior):
    paths = []
    for i, seed in enumerate((1, 1, 2)):
        out = tmp_path / f"zz{i}.csv"
        assert main(["simulate", "--manoeuvre", "zigzag", "--noise", "--seed", str(seed),
                     "--duration", "40", "--out", str(out)]) == 0  # fmt: skip
        paths.append(out)
    a, b, c = (pd.read_csv(p) for p in paths)
    assert list(a.columns) == list(REQUIRED) and len(a) == 401
    assert a.equals(b) and not a.equals(c)
    assert set(np.round(np.abs(a["delta_cmd"]), 4)) == {0.0, round(math.radians(20), 4)}
    df = load_log(paths[0], prior)  # the identification reader accepts what simulate writes
    assert df["t"].iloc[1] == pytest.approx(0.1) and len(df) == 401


@pytest.mark.parametrize(
    "name, content, match",
    [
        ("short.csv", "t,N,E,psi,u,v,r,T_cmd,delta_cmd\n0,0,0,0,1,0,0,50,0\n", "too short"),
        ("cols.csv", "t,N,E,psi\n" + "".join(f"{k},0,0,0\n" for k in range(200)),
         r"missing columns \['u', 'v', 'r', 'T_cmd', 'delta_cmd'\]"),
        ("text.csv", "t,N,E,psi,u,v,r,T_cmd,delta_cmd\n" + "a,b,c,d,e,f,g,h,i\n" * 200,
         "non-numeric or missing values"),
        ("log.txt", "whatever", "unknown log format"),
        ("bad.parquet", "not parquet", "not a readable parquet"),
        ("garbage.lsf", "not an lsf log at all, just text" * 10, "not an LSF"),
    ],
)  # fmt: skip
def test_bad_logs_clear_errors(tmp_path, capsys, name, content, match):
    path = tmp_path / name
    path.write_text(content)
    rc = main(["identify", str(path), "--out", str(tmp_path / "p.toml"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) <= 2 and name in err
    with pytest.raises(LogError, match=match):
        load_log(path, load_vessel("gretha"))


def test_time_going_backwards_is_refused(tmp_path, prior):
    df = simulate_manoeuvre(VesselModel(prior), "zigzag", duration=20)
    df.loc[50, "t"] = df.loc[10, "t"]
    path = tmp_path / "back.csv"
    df.to_csv(path, index=False)
    with pytest.raises(LogError, match="not strictly increasing"):
        load_log(path, prior)


def test_shared_auv_log_is_refused_clearly(prior, capsys, tmp_path):
    """The DUNE LAUV log loads through read_lsf, but it is a finned AUV: refused."""
    if not SHARED_LOG.is_file():
        pytest.skip(f"shared DUNE log not found at {SHARED_LOG}")
    with pytest.raises(
        LogError, match=r"4 steering servos \(fin_cmd_0.*'lauv-simulator-1'.*does not apply"
    ):
        load_log(SHARED_LOG, prior)
    rc = main(["identify", str(SHARED_LOG), "--out", str(tmp_path / "p.toml"), "--quiet"])
    assert rc == 2 and "steering servos" in capsys.readouterr().err


def _stamp(msg, t):
    msg.timestamp, msg.src, msg.src_ent, msg.dst, msg.dst_ent = t, 0x2801, 1, 0xFFFF, 0xFF
    return msg


def test_surface_vessel_lsf_is_mapped(tmp_path, prior):
    """A DUNE log of a surface vessel (one thruster, one steering servo) is accepted."""
    msgs, t0 = [], 1.7e9
    for k in range(150):
        es = _stamp(imcpy.EstimatedState(), t0 + 0.1 * k)
        es.lat, es.lon, es.x, es.y, es.z = 0.7188, -0.1519, 0.15 * k, 0.0, 0.0
        es.psi, es.u, es.v, es.r, es.vx, es.vy = 0.01 * k, 1.5, 0.02, 0.01, 1.5, 0.0
        thr = _stamp(imcpy.SetThrusterActuation(), t0 + 0.1 * k - 0.01)
        thr.id, thr.value = 0, 0.5
        servo = _stamp(imcpy.SetServoPosition(), t0 + 0.1 * k - 0.01)
        servo.id, servo.value = 0, 0.1
        msgs += [thr, servo, es]
    path = tmp_path / "Data.lsf"
    path.write_bytes(b"".join(m.serialize() for m in msgs))
    df = load_log(path, prior)
    assert len(df) == 150 and df["t"].iloc[0] == 0.0
    assert df["T_cmd"].to_numpy() == pytest.approx(0.5 * prior.T_max)
    assert df["delta_cmd"].to_numpy() == pytest.approx(0.1)
    assert df["u"].to_numpy() == pytest.approx(1.5) and df["psi"].iloc[-1] == pytest.approx(1.49)


def _two_vehicle_log(tmp_path):
    """A boat (0x2801: thruster and steering set-points) and an AUV it hears (0x0015: navigation
    only, at 5 m depth) in one DUNE log, as a boat's DUNE logs what it receives."""
    msgs, t0 = [], 1.7e9
    for k in range(150):
        es = _stamp(imcpy.EstimatedState(), t0 + 0.1 * k)
        es.lat, es.lon, es.x, es.y, es.z = 0.7188, -0.1519, 0.15 * k, 0.0, 0.0
        es.psi, es.u, es.v, es.r, es.vx, es.vy = 0.01 * k, 1.5, 0.02, 0.01, 1.5, 0.0
        auv = _stamp(imcpy.EstimatedState(), t0 + 0.1 * k + 0.02)
        auv.src = 0x0015
        auv.lat, auv.lon, auv.x, auv.y, auv.z, auv.depth = 0.7188, -0.1519, 50.0, 0.1 * k, 5, 5
        auv.psi, auv.u = 1.57, 1.0
        thr = _stamp(imcpy.SetThrusterActuation(), t0 + 0.1 * k - 0.01)
        thr.id, thr.value = 0, 0.5
        servo = _stamp(imcpy.SetServoPosition(), t0 + 0.1 * k - 0.01)
        servo.id, servo.value = 0, 0.1
        msgs += [thr, servo, es, auv]
    path = tmp_path / "Data.lsf"
    path.write_bytes(b"".join(m.serialize() for m in msgs))
    return path


def test_multi_vehicle_log_takes_the_actuated_vehicle_and_says_so(tmp_path, prior, capsys):
    """Issue 13 item 6: by default the vehicle with the actuator set-points, named on stdout."""
    path = _two_vehicle_log(tmp_path)
    df = load_log(path, prior)
    assert "identifying '0x2801', the one with actuator set-points" in capsys.readouterr().out
    assert len(df) == 150 and df["u"].to_numpy() == pytest.approx(1.5)
    assert df["T_cmd"].to_numpy() == pytest.approx(0.5 * prior.T_max)
    # --vehicle picks by IMC id (hex or decimal) or by name
    assert load_log(path, prior, "10241")["u"].to_numpy() == pytest.approx(1.5)
    with pytest.raises(LogError, match="'0x0015' is submerged"):
        load_log(path, prior, "0x15")
    with pytest.raises(LogError, match=r"no vehicle 'gretha' in the log \(vehicles: 0x0015, "):
        load_log(path, prior, "gretha")


def test_identify_cli_vehicle_option_gives_one_line(tmp_path, prior, capsys):
    path = _two_vehicle_log(tmp_path)
    rc = main(["identify", str(path), "--vehicle", "nemo", "--out", str(tmp_path / "p.toml"),
               "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "no vehicle 'nemo'" in err and len(err.strip().splitlines()) == 1


def test_two_thruster_lsf_is_mapped_to_total_and_differential_thrust(tmp_path):
    """Issue 15 item 3: a DUNE log of a boat with two fixed thrusters (id 0 port, id 1
    starboard, as DUNE's Otter) is mapped for a prior with actuation = "differential"."""
    otter = load_vessel("otter")
    msgs, t0 = [], 1.7e9
    for k in range(150):
        es = _stamp(imcpy.EstimatedState(), t0 + 0.1 * k)
        es.lat, es.lon, es.x, es.y, es.z = 0.7188, -0.1519, 0.1 * k, 0.0, 0.0
        es.psi, es.u, es.v, es.r, es.vx, es.vy = 0.0, 1.0, 0.0, 0.05, 1.0, 0.0
        for i, a in ((0, 0.6), (1, 0.2)):
            thr = _stamp(imcpy.SetThrusterActuation(), t0 + 0.1 * k - 0.01)
            thr.id, thr.value = i, a
            msgs.append(thr)
        msgs.append(es)
    path = tmp_path / "Data.lsf"
    path.write_bytes(b"".join(m.serialize() for m in msgs))
    df = load_log(path, otter)
    assert df["T_cmd"].to_numpy() == pytest.approx(0.4 * otter.T_max)
    assert df["delta_cmd"].to_numpy() == pytest.approx(0.2 * otter.delta_max)
    with pytest.raises(LogError, match="steering set-points|SetServoPosition") as err:
        load_log(path, prior=load_vessel("gretha"))  # a steerable prior needs the servo
    # ... and the message says why and what to try (review, session 5)
    assert "thrusters 0 and 1" in str(err.value) and "--vessel otter" in str(err.value)


def test_a_set_point_holds_from_the_grid_instant_nearest_its_logged_time():
    """Logged times drift by milliseconds against the median-step grid (DUNE's Otter log:
    0.18-3.6 ms ahead): each set-point holds over its own step, not the one after it (a
    plain zero-order hold took the previous row at 6,633 of 6,651 samples there). The CSV
    case too: a grid a few 1e-16 s short of the logged times."""
    from mpcasv.models.ident_table import hold_rows

    k = np.arange(200)
    grid = 0.1 * k
    for ahead in (3.6e-3, 7.3e-3, 4e-16, -0.04):  # logged time minus grid time (s)
        assert np.array_equal(hold_rows(grid + ahead, grid, 0.1)[1:], k[1:]), ahead
    # a row half a step or more after a grid instant is the next instant's
    assert hold_rows(grid + 0.06, grid, 0.1)[5] == 4


def _table_with_times(t, delta):
    n = len(t)
    return pd.DataFrame({"t": t, "N": np.zeros(n), "E": np.zeros(n), "psi": np.zeros(n),
                         "u": np.ones(n), "v": np.zeros(n), "r": np.zeros(n),
                         "T_cmd": np.full(n, 50.0), "delta_cmd": delta})  # fmt: skip


@pytest.mark.parametrize("seed", range(8))
def test_a_jittered_log_keeps_every_set_point_on_its_own_step(seed):
    """Logged times with +-4 ms of jitter: the grid is the span over its steps, so it does not
    drift against them (a median-step grid drifted 1 to 148 ms over 150 s on these seeds:
    steering switches a step off, N_rdot 23 % off in a new user's run, session 25)."""
    from mpcasv.models.ident_table import identification_table

    rng = np.random.default_rng(seed)
    k = np.arange(1501)
    delta = np.where((k // 75) % 2 == 0, 0.35, -0.35)  # a switch every 7.5 s
    table = identification_table(
        _table_with_times(0.1 * k + rng.uniform(-0.004, 0.004, k.size), delta), "jit.csv")
    assert len(table) == k.size
    assert np.array_equal(table["delta_cmd"].to_numpy(), delta)


def test_a_gap_in_the_log_is_refused_in_one_line():
    """A 3-s hole (30 samples missing) would be bridged by straight lines and shift the fit
    without a word: refused, naming where; a missing sample or two is bridged."""
    from mpcasv.models.ident_table import identification_table

    k = np.arange(1501)
    t, delta = 0.1 * k, np.where((k // 75) % 2 == 0, 0.35, -0.35)
    keep = (k < 500) | (k >= 530)
    with pytest.raises(LogError, match=r"gap.log: a gap of 3.1 s after t = 49.9 s") as err:
        identification_table(_table_with_times(t[keep], delta[keep]), "gap.log")
    assert "\n" not in str(err.value)
    one = k != 700  # one sample dropped: bridged, the grid keeps the log's step
    table = identification_table(_table_with_times(t[one], delta[one]), "drop.log")
    assert len(table) == k.size and table["t"].iloc[1] == pytest.approx(0.1)
