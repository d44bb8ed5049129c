"""Session 31's review of bad scenario input: every invalid scenario is refused at load, in one
line naming the file and the field, and the commands exit 2 (docs/experiments.md, "Bounds").

Before: an AUV route ``[ { waypoints = [] } ]`` passed the load and crashed the run with a
ValueError from the behaviour model (exit 1; inside ``mpcasv compare`` a job error instead of a
refusal up front); a lawnmower of 1e7 legs of 1e12 m hung; an AUV at 20 000 m, a waypoint 1e9 m
down and a plant step of 5 s were accepted; ``vessel = "nope"`` failed at the run without the
file or field; ``depth = nan`` read "should be >= 0"; inf passed wherever only ``>= 0`` was
asked (depths, spacings, event times, the acoustic noise, ...); a ping period of 1e-9 s looped
for ever.
"""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from pydantic import model_validator

from mpcasv.cli import main
from mpcasv.config import (
    DEPTH_MAX,
    DISTANCE_MAX,
    ConfigError,
    FieldError,
    Prob,
    between,
    frozen,
)
from mpcasv.sim.scenario import load_scenario

BASE = """\
name = "bad"
duration = 20.0
controller = "goto"
preset = "goto"
[asv]
vessel = "gretha"
execution = "gretha"
[asv.start]
N = -50.0
E = -50.0
speed = 0.0
depth = 0.0
[sim]
dt = 0.1
control_period = 1.0
[acoustics]
T0 = 5.0
d2 = 800.0
sigma_range = 0.5
p_good = 0.95
[navigation]
eps_a = 0.002

[[auv]]
name = "auv"
start = { N = 0.0, E = 0.0, depth = 20.0, speed = 0.0 }
limits = { speed_max = 2.0, depth_rate_max = 0.5 }
[auv.behaviour.plan]
speed = 1.5
surface_speed = 0.0
acceptance = 5.0
route = [ { waypoints = [[300.0, 0.0, 20.0]] } ]
"""
WAYPOINTS = "waypoints = [[300.0, 0.0, 20.0]]"
ROUTE = f"route = [ {{ {WAYPOINTS} }} ]"
PLAN = """[auv.behaviour.plan]
speed = 1.5
surface_speed = 0.0
acceptance = 5.0
""" + ROUTE


def _mower(length="300.0", spacing="50.0", legs="4", depth="20.0", heading="0.0") -> str:
    """One lawnmower route segment."""
    return (f"{{ lawnmower = {{ origin = [0.0, 0.0], length = {length}, spacing = {spacing}, "
            f"legs = {legs}, depth = {depth}, heading_deg = {heading} }} }}")  # fmt: skip


def _lawnmower(**kwargs) -> str:
    """A route of one lawnmower."""
    return f"route = [ {_mower(**kwargs)} ]"


def _events(*events: str) -> str:
    return ROUTE + "".join(f"\n[[auv.events]]\n{e}" for e in events)


#: (id, text replaced in BASE, replacement, the field the message must name, words it must hold):
#: the AUVs (empty lists, bounds, nan and inf, wrong types, speeds within the limits)
AUV_CASES = [
    ("empty waypoints", WAYPOINTS, "waypoints = []",
     "auv[0].behaviour.plan.route[0].waypoints", ["empty"]),
    ("empty route", ROUTE, "route = []", "auv[0].behaviour.plan.route", ["empty"]),
    ("empty waypoints of a switch event", ROUTE,
     _events("t = 5.0\nplan = { speed = 1.0, route = [ { waypoints = [] } ] }"),
     "auv[0].events[0].plan.route[0].waypoints", ["empty"]),
    ("lawnmower legs 1e7", ROUTE, _lawnmower(legs="10000000"),
     "auv[0].behaviour.plan.route[0].lawnmower.legs", ["[1, 5000]"]),
    ("lawnmower length 1e12", ROUTE, _lawnmower(length="1e12"),
     "auv[0].behaviour.plan.route[0].lawnmower.length", ["(0, 3.024e+06] m"]),
    ("lawnmower spacing inf", ROUTE, _lawnmower(spacing="inf"),
     "auv[0].behaviour.plan.route[0].lawnmower.spacing", ["not a finite number"]),
    ("lawnmower legs beyond the coordinates", ROUTE, _lawnmower(spacing="3e6", legs="3"),
     "auv[0].behaviour.plan.route[0].lawnmower", ["beyond the allowed 3.024e+06 m"]),
    ("lawnmower heading 1e300", ROUTE, _lawnmower(heading="1e300"),
     "auv[0].behaviour.plan.route[0].lawnmower.heading_deg", ["[-3600, 3600] deg"]),
    ("AUV depth 20000 m", "depth = 20.0, speed", "depth = 20000.0, speed",
     "auv[0].start.depth", ["20000 m", "[0, 11000] m"]),
    ("waypoint depth 1e9", WAYPOINTS, "waypoints = [[300.0, 0.0, 1e9]]",
     "auv[0].behaviour.plan.route[0].waypoints[0][2]", ["[0, 11000] m"]),
    ("waypoint N 1e300", WAYPOINTS, "waypoints = [[1e300, 0.0, 20.0]]",
     "auv[0].behaviour.plan.route[0].waypoints[0][0]", ["3.024e+06"]),
    ("lawnmower depth 12000", ROUTE, _lawnmower(depth="12000.0"),
     "auv[0].behaviour.plan.route[0].lawnmower.depth", ["[0, 11000] m"]),
    ("yoyo to 1e5 m", "acceptance = 5.0", "acceptance = 5.0\nyoyo = [10.0, 1e5]",
     "auv[0].behaviour.plan.yoyo[1]", ["[0, 11000] m"]),
    ("acceptance 1e300", "acceptance = 5.0", "acceptance = 1e300",
     "auv[0].behaviour.plan.acceptance", ["(0, 3.024e+06] m"]),
    ("speed_max 1e300", "speed_max = 2.0", "speed_max = 1e300",
     "auv[0].limits.speed_max", ["(0, 5] m/s"]),
    ("depth rate 1e300", "depth_rate_max = 0.5", "depth_rate_max = 1e300",
     "auv[0].limits.depth_rate_max", ["(0, 5] m/s"]),
    ("start speed above speed_max", "depth = 20.0, speed = 0.0", "depth = 20.0, speed = 3.0",
     "auv[0].start.speed", ["exceeds limits.speed_max 2.0"]),
    ("surface speed above speed_max", "surface_speed = 0.0", "surface_speed = 3.0",
     "auv[0].behaviour.plan.surface_speed", ["exceeds limits.speed_max 2.0"]),
    ("event at 1e9 s", ROUTE, _events('t = 1e9\nkind = "abort"'),
     "auv[0].events[0].t", ["[0, 604800] s"]),
    ("loiter event depth 1e9", ROUTE, _events('t = 5.0\nkind = "loiter"\ndepth = 1e9'),
     "auv[0].events[0].depth", ["[0, 11000] m"]),
    ("rise rate 1e300", ROUTE, _events('t = 5.0\nkind = "abort"\nrise_rate = 1e300'),
     "auv[0].events[0].rise_rate", ["(0, 5] m/s"]),
    ("pursuer period inf", PLAN, "[auv.behaviour.pursuer]\nspeed = 1.0\nupdate_period = inf",
     "auv[0].behaviour.pursuer.update_period", ["not a finite number"]),
    ("transit heading 1e20", PLAN, "[auv.behaviour.transit]\nheading_deg = 1e20\nspeed = 1.0",
     "auv[0].behaviour.transit.heading_deg", ["[-3600, 3600] deg"]),
    ("AUV depth nan", "depth = 20.0, speed", "depth = nan, speed",
     "auv[0].start.depth", ["nan is not a finite number"]),
    ("waypoint depth inf", WAYPOINTS, "waypoints = [[300.0, 0.0, inf]]",
     "auv[0].behaviour.plan.route[0].waypoints[0][2]", ["inf is not a finite number"]),
    ("event time nan", ROUTE, _events('t = nan\nkind = "abort"'),
     "auv[0].events[0].t", ["nan is not a finite number"]),
    ("depth as a string", "depth = 20.0, speed", 'depth = "20", speed',
     "auv[0].start.depth", ["valid number"]),
    ("legs as a float", ROUTE, _lawnmower(legs="4.5"),
     "auv[0].behaviour.plan.route[0].lawnmower.legs", ["valid integer"]),
]  # fmt: skip

#: the ASV, its vessel and execution files, the plant step, the channel, the current
WORLD_CASES = [
    ("plant step 5 s", "dt = 0.1\ncontrol_period = 1.0", "dt = 5.0\ncontrol_period = 5.0",
     "sim.dt", ["5 s", "[0.001, 0.2] s"]),
    ("plant step 1e-6 s (a million steps compiled)", "dt = 0.1", "dt = 1e-6",
     "sim.dt", ["[0.001, 0.2] s"]),
    ("control period 1e5 s", "control_period = 1.0", "control_period = 1e5",
     "sim.control_period", ["(0, 60] s"]),
    ("control period 2000 plant steps", "dt = 0.1\ncontrol_period = 1.0",
     "dt = 0.01\ncontrol_period = 20.0", "sim.control_period", ["2000 plant steps", "1000"]),
    ("ASV faster than its vessel", "speed = 0.0\ndepth = 0.0", "speed = 5.0\ndepth = 0.0",
     "asv.start.speed", ["u_max = 2.5 m/s", "'gretha'"]),
    ("ASV under water", "speed = 0.0\ndepth = 0.0", "speed = 0.0\ndepth = 5.0",
     "asv.start.depth", ["at the surface"]),
    ("ping period 1e-9 s (looped for ever)", "T0 = 5.0", "T0 = 1e-9",
     "acoustics.T0", ["[1, 604800] s"]),
    ("acoustic range 1e300", "d2 = 800.0", "d2 = 1e300", "acoustics.d2", ["(0, 20000] m"]),
    ("range noise inf", "sigma_range = 0.5", "sigma_range = inf",
     "acoustics.sigma_range", ["not a finite number"]),
    ("INS noise inf", "eps_a = 0.002", "eps_a = inf", "navigation.eps_a", ["not a finite number"]),
    ("current field knot at inf", "[navigation]", "[current_field]\nknots = [[inf, 0.0, 0.0]]\n"
     "[navigation]", "current_field.knots[0][0]", ["not a finite number"]),
    ("current field origin 1e300", "[navigation]", "[current_field]\norigin = [1e300, 0.0]\n"
     "[navigation]", "current_field.origin[0]", ["3.024e+06"]),
    ("unknown vessel", 'vessel = "gretha"', 'vessel = "nope"',
     "asv.vessel", ["unknown vessel 'nope'", "'dune-otter'", "'gretha'", "'otter'"]),
    ("unknown execution", 'execution = "gretha"', 'execution = "nope"',
     "asv.execution", ["unknown execution 'nope'", "'gretha'"]),
    ("probability nan", "p_good = 0.95", "p_good = nan",
     "acoustics.p_good", ["nan is not a finite number"]),
    ("unknown controller (refused at the run before)", 'controller = "goto"',
     'controller = "nope"', "controller",
     ["unknown controller 'nope'", "'hybrid-multi'", "'mpc-single'"]),
]  # fmt: skip

#: an [uncertain] table's supports within the same bounds
UNCERTAIN_CASES = [
    ("uncertain offset beyond the coordinates", "[navigation]",
     '[uncertain.auv.all]\noffset_N = { dist = "uniform", low = 0.0, high = 1e300 }\n'
     "[navigation]", "uncertain.auv (auv)", ["offset_N", "3.024e+06"]),
    ("uncertain ASV start beyond the coordinates", "[navigation]",
     '[uncertain.asv]\nstart_E = { dist = "uniform", low = 0.0, high = 1e300 }\n'
     "[navigation]", "uncertain.asv.start_E", ["3.024e+06"]),
    ("uncertain rotation beyond ten turns", "[navigation]",
     '[uncertain.auv.all]\nrotation_deg = { dist = "uniform", low = 0.0, high = 4000.0 }\n'
     "[navigation]", "uncertain.auv (auv)", ["rotation_deg", "+-3600 deg"]),
    ("uncertain event shift beyond the week", ROUTE,
     _events('t = 600000.0\nkind = "abort"') + '\n[uncertain.auv.all]\nevent_time_s = '
     '{ dist = "uniform", low = 0.0, high = 10000.0 }',
     "uncertain.auv (auv).event_time_s", ["604800 s"]),
    ("uncertain speed factor above speed_max by the surface speed", "surface_speed = 0.0\n"
     "acceptance = 5.0\n" + ROUTE, "surface_speed = 2.0\nacceptance = 5.0\n" + ROUTE
     + '\n[uncertain.auv.all]\nspeed_factor = { dist = "uniform", low = 0.9, high = 1.1 }',
     "uncertain.auv (auv).speed_factor", ["fastest speed 2.0"]),
]  # fmt: skip

CASES = AUV_CASES + WORLD_CASES + UNCERTAIN_CASES


def _write(tmp_path: Path, old: str, new: str) -> Path:
    assert old in BASE, old
    path = tmp_path / "bad.toml"
    path.write_text(BASE.replace(old, new, 1))
    return path


def test_the_base_scenario_is_valid(tmp_path):
    sc = load_scenario(_write(tmp_path, "", ""))
    assert sc.auv[0].start.depth == 20.0 and sc.sim.dt == 0.1


@pytest.mark.parametrize(("old", "new", "field", "words"), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])  # fmt: skip
def test_a_bad_scenario_is_refused_at_load_naming_the_file_and_the_field(
    tmp_path, capsys, old, new, field, words
):
    path = _write(tmp_path, old, new)
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    problems = [ln.strip() for ln in str(err.value).splitlines() if str(path) in ln]
    assert len(problems) == 1, str(err.value)
    assert problems[0].startswith(f"{path}: {field}: "), problems[0]
    assert all(w in problems[0] for w in words), (words, problems[0])
    # the command: exit 2, one line naming the file and the field, nothing written
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--quiet", "--no-plots"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f"{path}: {field}: " in lines[0] and all(w in lines[0] for w in words), lines[0]
    assert not out.exists()


def test_the_bounds_themselves_are_allowed(tmp_path):
    """Each bound is a value a file may give (the deepest ocean, 5000 legs, a 0.2-s step,
    60-s control periods of 600 plant steps, a vessel's top speed)."""
    text = (BASE.replace("depth = 20.0, speed", f"depth = {DEPTH_MAX}, speed")
            .replace("dt = 0.1\ncontrol_period = 1.0", "dt = 0.1\ncontrol_period = 60.0")
            .replace("speed = 0.0\ndepth = 0.0", "speed = 2.5\ndepth = 0.0")
            .replace(ROUTE, _lawnmower(legs="5000", length="10.0", spacing="1.0"))
            .replace("speed_max = 2.0", "speed_max = 5.0"))  # fmt: skip
    path = tmp_path / "edge.toml"
    path.write_text(text)
    sc = load_scenario(path)
    assert sc.auv[0].start.depth == DEPTH_MAX and sc.sim.n_sub == 600
    assert len(sc.auv[0].behaviour.plan.route[0].points()) == 10_000
    (tmp_path / "step.toml").write_text(BASE.replace("dt = 0.1", "dt = 0.2"))
    assert load_scenario(tmp_path / "step.toml").sim.dt == 0.2
    far = BASE.replace(WAYPOINTS, f"waypoints = [[{DISTANCE_MAX}, {-DISTANCE_MAX}, 0.0]]")
    (tmp_path / "far.toml").write_text(far)
    assert load_scenario(tmp_path / "far.toml").auv[0].behaviour.plan.route[0].waypoints


def _auvs(n: int) -> str:
    """BASE with ``n`` AUVs (the one of BASE and ``n - 1`` copies, each named apart)."""
    block = BASE[BASE.index("[[auv]]"):]
    return BASE + "".join("\n" + block.replace('name = "auv"', f'name = "auv{k}"')
                          for k in range(1, n))  # fmt: skip


def test_more_auvs_than_the_bound_are_refused_at_load(tmp_path, capsys):
    """500 [[auv]] entries were accepted (no bound on their number): the run went through the
    simulator and did not finish writing its figures in 5 minutes; an MPC would compile a
    problem for 500 AUVs. Now at most AUV_COUNT_MAX, the bound itself allowed."""
    from mpcasv.config import AUV_COUNT_MAX

    (tmp_path / "edge.toml").write_text(_auvs(AUV_COUNT_MAX))
    assert len(load_scenario(tmp_path / "edge.toml").auv) == AUV_COUNT_MAX
    path = tmp_path / "many.toml"
    path.write_text(_auvs(AUV_COUNT_MAX + 1))
    out = tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(out), "--quiet", "--no-plots"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f"{path}: auv: {AUV_COUNT_MAX + 1} AUVs: at most {AUV_COUNT_MAX}" in lines[0], lines
    assert not out.exists()


def test_more_than_ten_thousand_waypoints_in_one_plan_are_refused(tmp_path):
    route = f"route = [ {_mower(legs='5000')}, {_mower(legs='1')} ]"
    path = _write(tmp_path, ROUTE, route)
    with pytest.raises(ConfigError, match=r"auv\[0\]\.behaviour\.plan\.route: 10002 waypoints"):
        load_scenario(path)


def test_a_plant_step_above_the_execution_levels_filter_constant_is_refused(tmp_path):
    """dt <= 0.2 s is not enough with an execution level whose yaw derivative filter is faster:
    its Euler step diverges above 2 T_f (checked against the scenario's own execution file)."""
    from mpcasv.config import DATA_DIR

    text = (DATA_DIR / "execution" / "gretha.toml").read_text().replace("T_f = 0.2", "T_f = 0.05")
    (tmp_path / "fast.toml").write_text(text)
    path = _write(tmp_path, 'execution = "gretha"', 'execution = "fast.toml"')
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    assert f"{path}: sim.dt: 0.1 s is above the yaw derivative filter's T_f = 0.05 s" in str(
        err.value
    )


def test_a_models_own_refusal_is_named_at_load_whatever_the_checks_miss(tmp_path, monkeypatch):
    """The check of last resort: the AUV's behaviour objects are built at load, so a model's
    ValueError (the one behind the empty-waypoints crash) names the AUV and its behaviour."""
    import mpcasv.sim.auv_spec as auv_spec

    def refuse(*args, **kwargs):
        raise ValueError("a plan needs waypoints as rows (N, E, depth)")

    monkeypatch.setattr(auv_spec, "Plan", refuse)
    with pytest.raises(ConfigError) as err:
        load_scenario(_write(tmp_path, "", ""))
    assert "auv[0].behaviour: refused by the AUV model: a plan needs waypoints" in str(err.value)


def _goto_suite(tmp_path, extra: str = "", scenario: str = "bad.toml"):
    """A suite file ``s.toml`` running ``goto`` on ``scenario`` (seed 0, no plots), ``extra``
    lines added."""
    suite = tmp_path / "s.toml"
    suite.write_text(textwrap.dedent(f"""
        name = "s"
        scenarios = ["{scenario}"]
        seeds = [0]
        plots = "none"
    """) + extra + textwrap.dedent("""
        [[controllers]]
        label = "goto"
        name = "goto"
        preset = "goto"
    """))  # fmt: skip
    return suite


def test_compare_refuses_the_bad_scenario_up_front_instead_of_a_job_error(tmp_path, capsys):
    """The empty route was a job error in ``mpcasv compare`` (exit 1, the traceback in the
    table); now the suite is refused before any job starts."""
    path = _write(tmp_path, WAYPOINTS, "waypoints = []")
    suite = _goto_suite(tmp_path)
    out = tmp_path / "out"
    assert main(["compare", str(suite), "--out", str(out), "--workers", "1"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in lines[0], lines
    assert f"{path}: auv[0].behaviour.plan.route[0].waypoints: empty" in lines[0], lines[0]
    assert not (out / "parts").exists()


def test_compare_refuses_a_scenario_with_an_unknown_controller_its_entries_do_not_run(
        tmp_path, capsys):  # fmt: skip
    """A scenario's ``controller`` was looked up only when a run used it: a suite whose entries
    run their own controller ran the scenario with ``controller = "nope"`` without a word (and
    ``preset = "scenario"`` said the scenario's preset "is for 'nope'")."""
    path = _write(tmp_path, 'controller = "goto"', 'controller = "nope"')
    suite = _goto_suite(tmp_path, "duration = 2.0")
    out = tmp_path / "out"
    assert main(["compare", str(suite), "--out", str(out), "--workers", "1", "--quiet",
                 "--no-report"]) == 2  # fmt: skip
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f"{path}: controller: unknown controller 'nope'; known: [" in lines[0], lines[0]
    assert not (out / "parts").exists()


@pytest.mark.parametrize(("old", "new", "field"), [
    (WAYPOINTS, "waypoints = []", "auv[0].behaviour.plan.route[0].waypoints"),
    (ROUTE, _lawnmower(length="1e12", legs="10000000"), "lawnmower.length"),
], ids=["empty waypoints", "lawnmower 1e7 legs of 1e12 m"])  # fmt: skip
def test_the_installed_command_exits_2_with_one_line(tmp_path, old, new, field):
    """The reviewer's cases through a real process: a traceback and exit 1 (empty waypoints), a
    hang (1e7 legs of 1e12 m: both fields named, on one line)."""
    path = _write(tmp_path, old, new)
    proc = subprocess.run(
        [sys.executable, "-m", "mpcasv", "simulate", str(path), "--out", str(tmp_path / "o"),
         "--quiet", "--no-plots"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert str(path) in lines[0] and field in lines[0], lines[0]
    if "legs" in new:
        assert "lawnmower.legs" in lines[0]


def test_nan_and_inf_read_not_a_finite_number_for_every_kind_of_bound():
    """``>= 0`` (a depth), ``[0, 1]`` (a probability) and a range (a heading) alike."""
    from mpcasv.sim.scenario import scenario_from_dict

    auv = {"name": "a", "behaviour": {"transit": {"heading_deg": 0.0, "speed": 1.0}}}
    cases = [(("auv", 0, "start", "depth"), math.nan), (("acoustics", "p_sporadic"), math.inf),
             (("auv", 0, "behaviour", "transit", "heading_deg"), -math.inf)]  # fmt: skip
    for where, value in cases:
        data = {"name": "n", "duration": 10.0, "auv": [dict(auv, start={})], "acoustics": {}}
        node = data
        for key in where[:-1]:
            node = node[key]
        node[where[-1]] = value
        with pytest.raises(ConfigError) as err:
            scenario_from_dict(data, "n.toml")
        assert f"{value!r} is not a finite number" in str(err.value), str(err.value)


@frozen
class _Inner:
    depth: between(0, 10, "m", "shallow") = 0.0
    legs: between(1, 3, integer=True) = 1
    p: Prob = 0.5


@frozen
class _Outer:
    inner: tuple[_Inner, ...] = ()

    @model_validator(mode="after")
    def _two(self):
        if len(self.inner) > 1:
            raise FieldError("inner.1.legs", "not two")
        return self


def test_config_ranges_name_their_bound_and_a_field_below_the_model():
    """The pieces in mpcasv.config: a range type says its range and why; nan and inf are "not
    a finite number" (also for a probability: it read "should be <= 1"); a FieldError raised
    by a model's validator names the field below the model, not the model alone."""
    from mpcasv.config import parse

    def problem(data: dict) -> str:
        with pytest.raises(ConfigError) as err:
            parse(_Outer, data, "x.toml")
        lines = str(err.value).splitlines()
        assert len(lines) == 2, lines
        return lines[1].strip()

    assert problem({"inner": [{"depth": 11.0}]}) == (
        "x.toml: inner[0].depth: 11 m is outside the allowed range [0, 10] m (shallow)")
    assert problem({"inner": [{"legs": 4}]}) == (
        "x.toml: inner[0].legs: 4 is outside the allowed range [1, 3]")
    assert problem({"inner": [{"depth": math.nan}]}) == (
        "x.toml: inner[0].depth: nan is not a finite number")
    assert problem({"inner": [{"p": math.nan}]}) == "x.toml: inner[0].p: nan is not a finite number"
    assert problem({"inner": [{}, {}]}) == "x.toml: inner[1].legs: not two"
    assert "valid integer" in problem({"inner": [{"legs": 2.0}]})


def test_a_scenario_without_a_preset_runs_with_its_controllers_default(tmp_path, capsys):
    """``preset`` may be left out (default "default"): `mpcasv simulate` looked up a preset
    named 'default' and exited 2 ("unknown preset 'default'")."""
    path = _write(tmp_path, 'preset = "goto"\n', "")
    path.write_text(path.read_text().replace("duration = 20.0", "duration = 3.0"))
    assert load_scenario(path).preset == "default"
    out = tmp_path / "run"
    assert main(["simulate", str(path), "--out", str(out), "--quiet", "--no-plots"]) == 0, (
        capsys.readouterr().err)
    assert (out / "metrics.json").exists()


@pytest.mark.parametrize("controller", ["goto", "hybrid-single", "mpc-single"])
def test_a_scenario_without_a_preset_means_its_controllers_default_everywhere(controller):
    """The scenario format's ``preset = "default"`` (left out) is the controller's default
    preset in the one place presets are resolved (``preset_used``): paper-table, sitl and the
    estimator evaluation looked a preset named 'default' up and refused it ("unknown
    preset"); only simulate had its own exception."""
    from mpcasv.controllers import load_preset
    from mpcasv.controllers.registry import checked_preset, controller_kind, preset_used

    assert preset_used(controller, "default") == controller_kind(controller).default_preset
    assert load_preset(controller, "default") == load_preset(controller)
    _, params = checked_preset(controller, 1, "default")  # sitl's and deploy's check
    assert params == load_preset(controller)
