"""Load-time physics of a vessel file (``check_physics`` in mpcasv/models/params.py; session 45,
a new user's files): added-mass derivatives with the wrong sign, a yaw inertia below
``m x_g^2``, a mass matrix ``M = M_RB + M_A`` that is not positive definite and damping that
feeds energy in from rest are refused in one line naming the field, wherever a vessel is
loaded (``load_vessel``, a scenario's ``asv.vessel``, a suite, ``tune --vessel``), exit 2.
Before, the flipped added masses crashed ``simulate`` in a 40-line traceback (exit 1),
``compare`` started its jobs and failed each (exit 1), and ``tune yaw`` blamed the Nomoto
model (``K/T <= 0``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w
from shared_data import CASES, needs_shared
from test_experiments_bad_input import SCENARIO as DEMO
from test_scenario_bounds import _goto_suite

from mpcasv.cli import main
from mpcasv.config import DATA_DIR, ConfigError, load_toml, parse, resolve
from mpcasv.control.tuning_yaw import CourseUnstable, nomoto
from mpcasv.models.params import VesselParams, load_vessel
from mpcasv.models.vessel import IX, NX, VesselModel, mass_matrices

#: Gretha's added masses with the sign flipped (the new user's v_addedmass_sign.toml)
FLIPPED = {"X_udot": 91.0, "Y_vdot": 753.510998, "N_rdot": 1697.911449}


def _gretha(**values) -> dict:
    data = load_toml(resolve("vessels", "gretha"))
    data.update(values)
    return data


def _refused(field: str, *words: str, **values):
    with pytest.raises(ConfigError) as exc:
        parse(VesselParams, _gretha(**values), "v.toml")
    msg = " ".join(str(exc.value).split("\n")[1:]).strip()  # below "invalid configuration"
    assert msg.startswith(f"v.toml: {field}: "), msg
    for w in words:
        assert w in msg, (w, msg)
    return msg


@pytest.mark.parametrize("path", sorted((DATA_DIR / "vessels").glob("*.toml")), ids=str)
def test_every_shipped_vessel_file_loads(path):
    assert load_vessel(path).name


@needs_shared
def test_cybership2_loads_with_its_non_symmetric_damping():
    """CyberShip II (Skjetne et al. 2004) has a linear damping whose symmetric part is
    indefinite (Y_r = -7.25, N_v = 0.0313): the cross terms are deliberately not checked."""
    p = load_vessel(CASES / "vessels" / "cybership2.toml")
    D0 = -np.array([[p.Y_v, p.Y_r], [p.N_v, p.N_r]])
    assert np.linalg.eigvalsh(0.5 * (D0 + D0.T)).min() < 0


def test_flipped_added_mass_is_refused_naming_the_fields_and_the_fix():
    msg = _refused("X_udot", "X_udot = +91, Y_vdot = +753.511, N_rdot = +1697.91",
                   "<= 0 in Fossen's convention", "I_z - N_rdot = -160.011 kg m^2 <= 0",
                   "not positive definite", "did you mean X_udot = -91, Y_vdot = -753.511, "
                   "N_rdot = -1697.91?", **FLIPPED)  # fmt: skip
    assert "\n" not in msg
    # one alone, the mass matrix still positive definite: refused too (M_A >= 0)
    msg = _refused("X_udot", "X_udot = +91:", "did you mean X_udot = -91?", X_udot=91.0)
    assert "not positive definite" not in msg


def test_yaw_inertia_below_m_xg2_is_refused():
    _refused("I_z", "I_z = 1537.9 kg m^2 is not above m x_g^2 = 3640 kg m^2", "parallel-axis",
             x_g=-2.0)


def test_a_yaw_inertia_no_hull_of_its_size_has_is_refused():
    """A mass entered in tonnes (m = 1.4 beside I_z = 1537.9, a new user's file, session 45)
    loaded and simulated: the radius of gyration about the CG, 33 m, is more than any mass
    inside a 5.2 m x 2.15 m hull can have (Popoviciu: sqrt(L^2 + B^2) / 2 = 2.81 m)."""
    _refused("I_z", "radius of gyration about the centre of gravity", "= 33.14 m",
             "above sqrt(L^2 + B^2) / 2 = 2.813 m", "not tonnes", m=1.4)
    # at the bound itself: loads (gretha's own radius is 1.28 m)
    L, B, m = 5.2, 2.15, 910.0
    I_z = m * (L**2 + B**2) / 4 * (1 - 1e-9) + m * 0.21978**2
    assert parse(VesselParams, _gretha(I_z=I_z), "v.toml").I_z == I_z


def test_mass_matrix_not_positive_definite_through_the_coupling_is_refused():
    _refused("Y_rdot", "mass matrix M = M_RB + M_A is not positive definite",
             "m x_g - Y_rdot = 2800", Y_rdot=-3000.0, N_vdot=-3000.0)
    # not symmetric but positive definite (empirical Y_rdot != N_vdot): loads
    assert parse(VesselParams, _gretha(Y_rdot=-300.0, N_vdot=-100.0), "v.toml").Y_rdot == -300


@pytest.mark.parametrize("field", ["X_u", "Y_v", "N_r", "X_uu", "Y_vv", "N_rr"])
def test_damping_that_feeds_energy_in_from_rest_is_refused(field):
    value = -load_vessel("gretha").__getattribute__(field)
    _refused(field, f"{field} = +{value:.6g}", "gains energy", **{field: value})


def test_zero_linear_sway_damping_loads():
    """Fossen's Otter in the 3-DOF form has Y_v = 0 (cross-flow drag only)."""
    assert parse(VesselParams, _gretha(Y_v=0.0), "v.toml").Y_v == 0.0


def test_the_model_integrates_with_the_checked_mass_matrix():
    """One definition: the equations of motion solve with the M the load check tests (at rest,
    no Coriolis or damping: nu_dot = M^-1 tau)."""
    model = VesselModel(load_vessel("gretha"))
    P = model.params
    x = np.zeros(NX)
    x[IX["T"]], x[IX["delta"]] = 200.0, 0.3
    nu_dot = np.array(model.f(x, [200.0, 0.3], [0.0, 0.0])).ravel()[[IX["u"], IX["v"], IX["r"]]]
    M_RB, M_A = mass_matrices({k: getattr(P, k) for k in ("m", "I_z", "x_g", "X_udot",
                                                          "Y_vdot", "Y_rdot", "N_vdot", "N_rdot")})
    Y = -200.0 * np.sin(0.3)
    tau = [200.0 * np.cos(0.3), Y, P.x_p * Y]
    assert np.allclose(nu_dot, np.linalg.solve(np.array(M_RB + M_A), tau))


# --- every place a vessel is loaded, through the CLI --------------------------------------------

# the 20-s go-to scenario, on the flipped vessel
SCENARIO = DEMO.replace("[asv.start]", '[asv]\nvessel = "flipped.toml"\n[asv.start]', 1)


@pytest.fixture
def flipped(tmp_path) -> Path:
    data = _gretha(**FLIPPED)
    (tmp_path / "flipped.toml").write_text(tomli_w.dumps(data))
    (tmp_path / "demo.toml").write_text(SCENARIO)
    _goto_suite(tmp_path, scenario="demo.toml")
    return tmp_path


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "{d}/demo.toml", "--out", "{d}/out"],
        ["compare", "{d}/s.toml", "--out", "{d}/out", "--workers", "1"],
        ["tune", "yaw", "--vessel", "{d}/flipped.toml", "--out", "{d}/out", "--quiet"],
    ],
    ids=["simulate", "compare", "tune-yaw"],
)
def test_every_command_refuses_the_file_before_running(flipped, capsys, argv):
    argv = [a.format(d=flipped) for a in argv]
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "Traceback" not in err[0], (rc, err)
    assert "flipped.toml: X_udot: X_udot = +91" in err[0] and "did you mean" in err[0], err[0]
    # the scenario's asv.vessel names the file, without a second "invalid configuration"
    # heading in the middle of the line (a new user's reading, session 45)
    assert err[0].count("invalid configuration") <= 1, err[0]
    assert not (flipped / "out").exists()


def test_complex_sway_yaw_poles_name_the_block_and_the_mass_terms():
    """Complex sway-yaw poles (here a strong destabilising N_v = +3000 N s, which the load
    does not refuse: published models have such cross terms): tune yaw says why its poles
    are complex instead of only that they are. (A mass in tonnes, which gave such poles too,
    is refused at load since session 45: the radius-of-gyration bound above.)"""
    model = VesselModel(load_vessel("gretha").with_coeffs(N_v=3000.0))
    with pytest.raises(CourseUnstable) as exc:
        nomoto(model, 1.0)
    msg = str(exc.value)
    assert "complex or zero poles" in msg and "the coupling a_vr a_rv = -0.407 m/s" in msg, msg
    assert "is below -((a_vv - a_rr)/2)^2 = -0.0565 1/s^2" in msg, msg
    assert "mass terms: m = 910 kg, added -X_udot = 91 kg, -Y_vdot = 753.511 kg" in msg, msg
