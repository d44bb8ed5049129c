"""Bad input of `mpcasv tune yaw|speed` and `mpcasv identify` (session 17 attack): one line on
stderr naming the option (or file) and the value, exit 2, nothing written; a design or an
identification that runs but fails its acceptance exits 1 without warnings and is not written
(tune) or is marked (identify)."""

from __future__ import annotations

import math
import shutil
import warnings

import numpy as np
import pytest

from mpcasv.cli import main
from mpcasv.config import DATA_DIR


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
        ("speed", ["--design-speed", "100"], ["--design-speed 100", "(0, 2.5] m/s"]),  # Kp = 0
        ("speed", ["--u-ff", "3"], ["--u-ff 3", "(0, 2.5] m/s"]),
        ("yaw", ["--wn", "100"], ["--wn 100", "1/T_delta = 3.33 rad/s"]),  # overflow warnings
        ("yaw", ["--wn-per-speed", "2"], ["--wn-per-speed 2", "1/T_delta"]),
        ("yaw", ["--dt", "100"], ["--dt 100", "T_f (--T-f) = 0.2 s", "--dt <= 0.2"]),
        ("yaw", ["--T-f", "0.05"], ["--dt 0.1", "--T-f", "--dt <= 0.05"]),
        ("speed", ["--w", "100"], ["--w 100", "1/T_thrust = 2 rad/s"]),  # overflow warnings
        ("speed", ["--dt", "100"], ["--dt 100", "T_thrust", "--dt <= 0.5"]),
        ("yaw", ["--base", "nope"], ["--base nope", "unknown execution 'nope'"]),  # "executio"
    ],
)
def test_bad_tuning_input_is_one_line_and_writes_nothing(tmp_path, capsys, loop, args, words):
    out = tmp_path / "out"
    _refused(capsys, ["tune", loop, *args, "--out", str(out), "--quiet"], *words)
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
