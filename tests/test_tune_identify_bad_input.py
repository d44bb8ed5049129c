"""Bad input of `mpcasv tune yaw|speed` and `mpcasv identify` (session 17 attack): one line on
stderr naming the option (or file) and the value, exit 2, nothing written; a design or an
identification that runs but fails its acceptance exits 1 without warnings and is not written
(tune) or is marked (identify)."""

from __future__ import annotations

import math
import shutil
import warnings

import numpy as np
import pandas as pd
import pytest

from mpcasv.cli import main
from mpcasv.config import DATA_DIR
from mpcasv.control.manoeuvres import simulate_manoeuvre
from mpcasv.errors import LogError
from mpcasv.models.params import load_vessel
from mpcasv.models.vessel import VesselModel


def _refused(capsys, argv, *words):
    """``argv`` exits 2 with one stderr line holding every word, and no traceback (a usage
    error leaves through argparse's SystemExit)."""
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    for w in words:
        assert w in err[0], (w, err[0])
    return err[0]


@pytest.mark.parametrize(
    ("loop", "args", "words"),
    [
        ("yaw", ["--speeds", "1,1"], ["--speeds 1,1", "more than once"]),  # pydantic traceback
        ("yaw", ["--speeds", "2,1"], ["--speeds 2,1", "strictly increasing"]),
        ("yaw", ["--speeds", ",,"], ["--speeds", "',,'"]),  # pydantic traceback
        ("speed", ["--u-ff", "0.4,0.4"], ["--u-ff 0.4,0.4", "more than once"]),  # zip() error
        ("speed", ["--distance", "50,50"], ["--distance 50,50", "more than once"]),
        # inside the arrival circle: every turn "done" in 0.0 s over 0.0 m, recommended
        ("speed", ["--distance", "10,3"], ["--distance 3 m", "inside the 5 m arrival circle"]),
        ("speed", ["--design-speed", "100"], ["--design-speed 100", "(0, 2.5] m/s"]),  # Kp = 0
        ("speed", ["--u-ff", "3"], ["--u-ff 3", "(0, 2.5] m/s"]),
        ("yaw", ["--wn", "100"], ["--wn 100", "1/T_delta = 3.33 rad/s"]),  # overflow warnings
        ("yaw", ["--wn-per-speed", "2"], ["--wn-per-speed 2", "1/T_delta"]),
        ("yaw", ["--dt", "100"], ["--dt 100", "T_f (--T-f) = 0.2 s", "--dt <= 0.2"]),
        ("yaw", ["--T-f", "0.05"], ["--dt 0.1", "--T-f", "--dt <= 0.05"]),
        ("speed", ["--w", "100"], ["--w 100", "1/T_thrust = 2 rad/s"]),  # overflow warnings
        ("speed", ["--dt", "100"], ["--dt 100", "T_thrust", "--dt <= 0.5"]),
        ("speed", ["--u-ff", "0.6", "--k-u", "10"],  # k_u = 10 was recommended and written
         ["--k-u 10", "above --u-cmd-max 3.0976 m/s", "no pair"]),
        ("yaw", ["--base", "nope"], ["--base nope", "unknown execution 'nope'"]),  # "executio"
    ],
)
def test_bad_tuning_input_is_one_line_and_writes_nothing(tmp_path, capsys, loop, args, words):
    out = tmp_path / "out"
    _refused(capsys, ["tune", loop, *args, "--out", str(out), "--quiet"], *words)
    assert not out.exists()


def test_a_base_files_yaw_filter_is_checked_against_the_step_as_an_option_is(tmp_path, capsys):
    """`tune speed --base FILE` with T_f = 0.02 s ran its turns at 0.1 s (> 2 T_f: the
    forward-Euler yaw-rate filter diverges) unrefused: the --dt/--T-f check covered options
    only. Likewise `tune yaw --dt 0.01 --T-f 0.05`: its nonlinear step runs at 0.1 s."""
    text = (DATA_DIR / "execution" / "gretha.toml").read_text().replace("T_f = 0.2", "T_f = 0.02")
    base = tmp_path / "tf.toml"
    base.write_text(text)
    out = tmp_path / "out"
    _refused(capsys, ["tune", "speed", "--base", str(base), "--out", str(out), "--quiet"],
             f"T_f (--base {base}) = 0.02 s", "the nonlinear checks' step", "T_f >= 0.1 s")
    _refused(capsys, ["tune", "yaw", "--dt", "0.01", "--T-f", "0.05", "--out", str(out),
                      "--quiet"], "T_f (--T-f) = 0.05 s", "the nonlinear checks' step")
    assert not out.exists()


def _quiet_run(argv) -> tuple[int, list]:
    """Run ``argv``; the numeric warnings it raised (overflow, badly conditioned filters)."""
    from scipy.signal import BadCoefficients

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main(argv)
    return rc, [w for w in caught if issubclass(w.category, (RuntimeWarning, BadCoefficients))]


@pytest.mark.parametrize(
    ("loop", "args"),
    [
        ("yaw", ["--speeds", "2", "--wn", "3"]),  # inside the limit, unstable: exit 1
        ("speed", ["--speeds", "1", "--w", "1.99", "--dt", "0.5", "--u-ff", "0.6", "--k-u",
                   "1.59", "--distance", "50"]),  # fmt: skip
    ],
)
def test_a_failing_design_keeps_the_toml_and_prints_no_warnings(tmp_path, capsys, loop, args):
    toml = tmp_path / "execution.toml"
    shutil.copy(DATA_DIR / "execution" / "gretha.toml", toml)
    before = toml.read_text()
    rc, caught = _quiet_run(["tune", loop, *args, "--out", str(tmp_path / "o"), "--toml",
                             str(toml), "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 1 and "FAIL" in out and f"{toml} NOT written" in out, out
    assert toml.read_text() == before  # a failing design is not left where it would be used
    assert not caught, [str(w.message) for w in caught]


def test_a_speed_loop_with_kp_clipped_to_zero_prints_no_warnings(tmp_path, capsys):
    rc, caught = _quiet_run(["tune", "speed", "--design-speed", "2.5", "--w", "0.05", "--speeds",
                             "2.5", "--u-ff", "0.6", "--k-u", "1.59", "--distance", "50",
                             "--out", str(tmp_path), "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert rc in (0, 1) and "badly conditioned coefficients" in out, out
    assert not caught, [str(w.message) for w in caught]


def test_a_diverged_response_never_reads_as_settled():
    from mpcasv.control.tuning import settling_time

    t = np.arange(0.0, 10.0, 1.0)
    err = np.full(len(t), np.nan)  # a response that overflowed: nan, not "within the band"
    assert settling_time(t, err, 0.1) == math.inf


# --- identify ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def zigzag():
    # 121 s: long enough to identify from (1,203 samples at the default --validation)
    return simulate_manoeuvre(VesselModel(load_vessel("gretha")), "zigzag", duration=121.0)


def test_a_steering_that_never_varies_is_refused_naming_the_coefficient(tmp_path, capsys,
                                                                         zigzag):  # fmt: skip
    df = zigzag.copy()
    df["delta_cmd"] = 0.0  # the steering column zeroed while the boat turns
    log = tmp_path / "constant steering.csv"
    df.to_csv(log, index=False)
    out = tmp_path / "p.toml"
    _refused(capsys, ["identify", str(log), "--out", str(out), "--quiet"],
             "Y_uudelta cannot be identified", str(log), "delta_cmd never varies (always 0)",
             "--coeffs")  # fmt: skip
    assert not out.exists() and not (tmp_path / "p-report").exists()


def test_collinear_and_singular_fits_are_named():
    from mpcasv.models.ident_checks import check_covariance, unidentifiable

    rng = np.random.default_rng(0)
    J = rng.normal(size=(50, 3))
    assert unidentifiable(J, ("a", "b", "c")) == ([], "")
    J[:, 2] = 2.0 * J[:, 0]
    assert unidentifiable(J, ("a", "b", "c")) == (["a", "c"], "collinear")
    J[:, 1] = 0.0
    assert unidentifiable(J, ("a", "b", "c")) == (["b"], "zero")
    with pytest.raises(LogError, match=r"^X_u cannot be identified from x\.csv: .*not finite"):
        check_covariance({"X_u": math.nan, "X_uu": 0.1}, ["x.csv"])


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--vehicle", "nobody"], ["--vehicle nobody", "DUNE log"]),  # was ignored silently
        (["--coeffs", "X_u,X_u"], ["--coeffs X_u,X_u", "X_u given more than once"]),
    ],
)
def test_identify_options_that_would_be_misread(tmp_path, capsys, zigzag, args, words):
    log = tmp_path / "z.csv"
    zigzag.to_csv(log, index=False)
    out = tmp_path / "p.toml"
    _refused(capsys, ["identify", str(log), *args, "--out", str(out), "--quiet"], *words)
    assert not out.exists()


def test_identify_on_a_folder_says_it_is_a_folder(tmp_path, capsys):
    out = tmp_path / "p.toml"
    _refused(capsys, ["identify", str(tmp_path), "--out", str(out), "--quiet"],
             f"{tmp_path}: a folder, not a log file")  # fmt: skip
    assert not out.exists()


def test_a_negative_validation_fit_exits_1_and_marks_the_toml(tmp_path, capsys, zigzag,
                                                              monkeypatch):  # fmt: skip
    """The identification itself is replaced (a full fit takes half a minute): what is
    checked is the verdict on its held-out fits."""
    import mpcasv.io.identlog as identlog
    from mpcasv.models.identify import OUTPUTS, Identification

    def fake(logs, prior, coeffs, **kw):
        fits = {"train": {c: {"rmse": 0.1, "fit_pct": 50.0} for c in OUTPUTS},
                "validation": {c: {"rmse": 0.1, "fit_pct": -20.0 if c == "u" else 60.0}
                               for c in OUTPUTS}}  # fmt: skip
        Y = np.zeros((4, 10))
        return Identification(params=prior, coeffs=("X_u",), theta=np.ones(3),
                              rel_std={"X_u": 0.05}, current=(0.0, 0.0),
                              metrics={s: fits for s in ("prior", "equation_error",
                                                         "simulation_error")},
                              replay={"train": (Y, Y), "validation": (Y, Y)})  # fmt: skip

    monkeypatch.setattr(identlog, "identify", fake)
    log = tmp_path / "z.csv"
    zigzag.to_csv(log, index=False)
    out = tmp_path / "p.toml"
    assert main(["identify", str(log), "--coeffs", "X_u", "--out", str(out), "--quiet"]) == 1
    text = capsys.readouterr().out
    assert "validation FAIL: held-out fit below 0 % for u -20.0 %" in text, text
    assert "Validation (held-out fit >= 0 % on every channel): FAIL: u -20.0 %" in text
    assert "# VALIDATION FAILED: held-out fit below 0 % for u" in out.read_text()


@pytest.mark.parametrize("name", ["zigzag", "turning-circle"])
def test_a_steering_manoeuvre_that_never_steers_is_refused(tmp_path, capsys, name):
    """`simulate --manoeuvre zigzag --delta 0` wrote a straight line with exit 0: the zigzag
    and the turning circle identify the steering by +-delta, so 0 is refused in one line,
    nothing written; 20 is not."""
    out = tmp_path / "m.csv"
    _refused(capsys, ["simulate", "--manoeuvre", name, "--delta", "0", "--out", str(out)],
             "--delta 0", name, "never steers")  # fmt: skip
    assert not out.exists()
    df = simulate_manoeuvre(VesselModel(load_vessel("gretha")), name, delta_deg=20.0,
                            duration=40.0)  # fmt: skip
    assert df["delta_cmd"].abs().max() > 0


def test_speed_steps_may_run_straight(tmp_path, capsys):
    """speed-steps identifies the surge (it steers only by doublets of 0.3 delta): `--delta 0`
    is a legitimate straight run, exit 0, the thrust stepped and the steering never set."""
    out = tmp_path / "s.csv"
    rc = main(["simulate", "--manoeuvre", "speed-steps", "--delta", "0", "--duration", "60",
               "--out", str(out)])  # fmt: skip
    assert rc == 0 and out.exists(), capsys.readouterr().err
    df = pd.read_csv(out)
    assert (df["delta_cmd"] == 0).all() and df["T_cmd"].nunique() >= 2
    assert df["psi"].abs().max() < 1e-9 and df["u"].max() > df["u"].iloc[0] + 0.3


@pytest.mark.parametrize("loop", ["yaw", "speed"])
def test_speeds_that_start_with_a_minus_say_how_to_give_them(tmp_path, capsys, loop):
    """`--speeds -1,1` was argparse's bare "expected one argument" (a value starting with '-'
    that is not one number reads as an option): the one line says to join it, and the
    joined form reaches the speeds' own check (exit 2 either way, nothing written)."""
    out = tmp_path / "o"
    _refused(capsys, ["tune", loop, "--speeds", "-1,1", "--out", str(out), "--quiet"],
             "--speeds", "comma-separated", "--speeds=-1,1")  # fmt: skip
    _refused(capsys, ["tune", loop, "--speeds=-1,1", "--out", str(out), "--quiet"],
             "--speeds [-1.0] m/s outside (0, 2.5] m/s")  # fmt: skip
    assert not out.exists()
