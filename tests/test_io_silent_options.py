"""Options and configuration fields of the deploy, SITL and replay that were accepted and had
no effect (session 24 audit): each now works or is refused up front in one line naming it.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import tomli_w

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.interface import ASVState, AUVEstimate, Observation
from mpcasv.io import replay as replay_mod
from mpcasv.io.config import WatchdogSpec, deploy_config_from_dict
from mpcasv.io.records import cmd_to_dict, obs_to_dict
from mpcasv.models.params import load_vessel

BASE = {
    "origin": {"lat_deg": 63.4406, "lon_deg": 10.3530},
    "controller": {"name": "hybrid-single", "preset": "paper1-field"},
    "vehicle": [{"role": "asv", "id": 0x2801}, {"role": "auv", "id": 0x2802}],
}


def _config(**change) -> dict:
    """BASE with top-level sections merged into (``controller``, ``link``, ...)."""
    data = json.loads(json.dumps(BASE))
    for key, value in change.items():
        data[key] = data.get(key, {}) | value if isinstance(value, dict) else value
    return data


def _refused(argv: list, capsys, *words: str) -> str:
    """`mpcasv ARGV` exits 2 with one error line containing every word; returns the line."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    return err


def _deploy_refused(data: dict, tmp_path: Path, capsys, *words: str) -> None:
    """The configuration is refused at load (ConfigError naming every word) and `mpcasv
    deploy CONFIG --prepare` exits 2 in one line naming them."""
    with pytest.raises(ConfigError) as err:
        deploy_config_from_dict(data, "deploy.toml")
    for w in words:
        assert w in str(err.value), (w, str(err.value))
    path = tmp_path / "deploy.toml"
    path.write_text(tomli_w.dumps(data | {"log": {"dir": str(tmp_path / "log")}}))
    _refused(["deploy", path, "--prepare"], capsys, str(path), *words)


def _deploy_log(folder: Path, controller: dict, acoustics: dict | None = None) -> Path:
    """A deploy log of one decision whose configuration has ``controller`` (and
    ``acoustics``), ended normally (its ``summary`` record)."""
    from mpcasv.controllers import make_controller

    obs = Observation(0.0, ASVState(0.0, 0.0, 0.0), True,
                      (AUVEstimate(200.0, 50.0, 10.0, t_last_fix=0.0),))  # fmt: skip
    ctl = make_controller(controller["name"], 1, controller.get("preset"))
    ctl.reset(1)
    guard = {"stale_s": 5.0, "lost_s": 60.0, "v_max": 1.5, "w_max": 0.5, "r_keep": 10.0,
             "margin_m": 5.0, "speed": 1.5}  # fmt: skip
    config = {"controller": {"preset": None, "overrides": {}, **controller},
              "watchdog": dataclasses.asdict(WatchdogSpec())}
    if acoustics is not None:
        config["acoustics"] = acoustics
    started = {"kind": "event", "event": "started", "guard": guard, "config": config}
    step = {"kind": "step", "t": 0.0, "clock": 0.0, "obs": obs_to_dict(obs),
            "cmd": cmd_to_dict(ctl.step(obs)), "override": None, "status": ["ok"],
            "ages": [0.0]}  # fmt: skip
    summary = {"kind": "summary", "t": 1.0}  # a deploy that ended normally
    log = folder / "deploy.jsonl"
    log.write_text("".join(json.dumps(r) + "\n" for r in (started, step, summary)))
    return log


# --- 1. replay builds the controller for the boat the deploy drove -------------------------

def test_replay_builds_the_controller_for_the_logged_vessel_and_acoustics(tmp_path, monkeypatch):
    """`replay` built the controller for the default boat (Gretha, default acoustics) whatever
    the logged `controller.vessel` and `[acoustics]`; the deploy built it for those
    (deploy_boat). It now builds it for the logged boat, as the deploy did."""
    boats = []
    real = replay_mod.make_controller

    def spy(*args, **kw):
        boats.append(kw.get("boat"))
        return real(*args, **kw)

    monkeypatch.setattr(replay_mod, "make_controller", spy)
    acoustics = {"T0": 7.0, "d1": 300.0, "d2": 600.0}
    log = _deploy_log(tmp_path, {"name": "hybrid-single", "vessel": "otter"}, acoustics)
    rep = replay_mod.replay(log)
    assert (rep.n_steps, rep.n_differ) == (1, 0)
    (boat,) = boats
    assert boat is not None
    assert boat.vessel == load_vessel("otter")
    assert (boat.acoustics.T0, boat.acoustics.d1, boat.acoustics.d2) == (7.0, 300.0, 600.0)


def test_replay_of_a_log_without_vessel_or_acoustics_uses_the_deploy_defaults(tmp_path):
    log = _deploy_log(tmp_path, {"name": "hybrid-single"})
    boat = replay_mod.logged_boat(json.loads(log.read_text().splitlines()[0])["config"])
    assert boat.vessel == load_vessel("gretha") and boat.acoustics.T0 == 5.0


# --- 2. a vehicle's tcp address with the UDP transport ------------------------------------

def test_a_vehicle_tcp_address_with_the_udp_transport_is_refused(tmp_path, capsys):
    """`[[vehicle]] tcp = ...` with link.transport = 'udp' (the default) was loaded and never
    read (the link binds UDP); refused at load, naming the fields."""
    veh = [{"role": "asv", "id": 0x2801, "tcp": "127.0.0.1:6001"}, {"role": "auv", "id": 0x2802}]
    _deploy_refused(_config(vehicle=veh), tmp_path, capsys, "vehicle.tcp", "link.transport",
                    "0x2801")  # fmt: skip
    ok = _config(vehicle=[v | {"tcp": "127.0.0.1:6001"} for v in veh], link={"transport": "tcp"})
    assert deploy_config_from_dict(ok).link.transport == "tcp"


# --- 3. deploy --prepare with the run's options ---------------------------------------------

@pytest.mark.parametrize("option", [["--dry-run"], ["--duration", "5"]])
def test_deploy_prepare_refuses_the_options_of_a_run(option, tmp_path, capsys):
    """`deploy CONFIG --prepare` built the controller and exited, silently ignoring --dry-run
    and --duration; the combination is refused in one line naming both options, before
    anything is built."""
    path = tmp_path / "deploy.toml"
    path.write_text(tomli_w.dumps(_config(log={"dir": str(tmp_path / "log")})))
    _refused(["deploy", path, "--prepare", *option], capsys, "--prepare", option[0])
    assert not (tmp_path / "log").exists()


# --- 4. controller.scenario without the plan estimator -------------------------------------

@pytest.mark.parametrize("estimator", ["perfect", "acoustic", "kalman"])
def test_a_scenario_without_the_plan_estimator_is_refused(estimator, tmp_path, capsys):
    """`controller.scenario` was loaded and checked (file, AUV count) and then read by no
    estimator but 'plan'; refused at load naming the field and the estimator."""
    case3 = str(Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml")
    ctl = {"name": "hybrid-single", "estimator": estimator, "scenario": case3}
    _deploy_refused(_config(controller=ctl), tmp_path, capsys, "controller.scenario",
                    "estimator = 'plan'", repr(estimator))  # fmt: skip
    ok = deploy_config_from_dict(_config(controller=ctl | {"estimator": "plan"}))
    assert ok.controller.scenario == case3


# --- 5. [watchdog] fields the controller or mode never reads -------------------------------

@pytest.mark.parametrize("field, value, ctl, words", [
    ("keep_out_m", 30.0, {"name": "hybrid-single"}, ["hybrid-single", "domain's r_in"]),
    ("guard_speed", 1.0, {"name": "hybrid-single"}, ["hybrid-single", "'speed'"]),
    ("guard_speed", 1.0, {"name": "goto", "preset": "goto"}, ["goto", "'speed'"]),
])  # fmt: skip
def test_a_guard_field_the_controller_replaces_is_refused(field, value, ctl, words, tmp_path,
                                                          capsys):  # fmt: skip
    """`watchdog.keep_out_m` is read only for a controller without avoid sphere or domain,
    `guard_speed` only for one without a 'speed' (mpcasv.io.deploystep.guard_params); set
    for one that has them it was silently unused. Refused at load when set explicitly."""
    data = _config(controller=ctl, watchdog={field: value})
    _deploy_refused(data, tmp_path, capsys, f"watchdog.{field}", *words)
    deploy_config_from_dict(_config(controller=ctl))  # the default is not refused


def test_keep_out_m_is_accepted_for_a_controller_without_a_domain():
    """goto has no domain: the guard keeps out watchdog.keep_out_m, so it may be set."""
    from mpcasv.controllers import make_controller
    from mpcasv.io.deploystep import guard_params

    cfg = deploy_config_from_dict(_config(controller={"name": "goto", "preset": "goto"},
                                          watchdog={"keep_out_m": 30.0}))  # fmt: skip
    assert guard_params(cfg.watchdog, make_controller("goto", 1)).r_keep == 30.0


def test_the_propeller_threshold_without_thrusters_is_refused(tmp_path, capsys):
    """`propeller_on_threshold` is read only from thruster messages; with `propeller =
    "command"` it was silently unused. Refused when set explicitly."""
    wd = {"propeller": "command", "propeller_on_threshold": 0.1}
    _deploy_refused(_config(watchdog=wd), tmp_path, capsys, "watchdog.propeller_on_threshold",
                    "'command'")  # fmt: skip
    deploy_config_from_dict(_config(watchdog={"propeller": "command"}))
    deploy_config_from_dict(_config(watchdog=wd | {"propeller": "thruster"}))


# --- 6. sitl --controller / --preset --------------------------------------------------------

@pytest.mark.parametrize("option", [["--controller", "goto"], ["--preset", "goto"]])
def test_sitl_has_no_controller_or_preset_option(option, tmp_path, capsys):
    """`sitl --controller/--preset` were validated and thrown away (the world judges by the
    scenario's controller and preset; the deploy runs the controller), and --help said the
    world used them. Removed: argparse refuses them in one line naming the option."""
    case3 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml"
    _refused(["sitl", case3, *option, "--out", tmp_path / "s"], capsys,
             f"unrecognized arguments: {' '.join(option)}")  # fmt: skip
    assert not (tmp_path / "s").exists()


# --- 7. sitl --lockstep --reaction ---------------------------------------------------------

def test_sitl_refuses_reaction_with_lockstep(tmp_path, capsys):
    """`sitl --lockstep --reaction R` waited without limit whatever R; refused in one line
    naming both options, before the world is built. --lockstep alone is unaffected."""
    case3 = Path(__file__).resolve().parents[1] / "experiments" / "scenarios" / "case3.toml"
    _refused(["sitl", case3, "--lockstep", "--reaction", "0.5", "--out", tmp_path / "s"],
             capsys, "--reaction 0.5", "--lockstep")  # fmt: skip
    assert not (tmp_path / "s").exists()


def test_replay_says_a_logged_vessel_it_cannot_load_came_from_the_log(tmp_path):
    """A relative vessel path in the log is the deploy's, not the replay's working folder's:
    the refusal names the logged field (it read as if the user had given the name)."""
    from mpcasv.io.replay import logged_boat

    with pytest.raises(ConfigError, match=r"x\.jsonl: the logged controller\.vessel "
                                          r"'vessels/mine\.toml': .*replay from its folder"):
        logged_boat({"controller": {"vessel": "vessels/mine.toml"}}, "x.jsonl")


def test_sitl_options_refuse_reaction_with_lockstep_from_python_too():
    """The check is the options' own (it was only the command line's): a library caller
    giving both was silently accepted."""
    from mpcasv.io.sitloptions import REACTION, SitlOptions
    from mpcasv.sim.scenario import load_scenario

    sc = load_scenario(Path(__file__).resolve().parents[1] / "experiments" / "scenarios"
                       / "case3.toml")  # fmt: skip
    with pytest.raises(ConfigError, match="--reaction 0.5 has no effect with --lockstep"):
        SitlOptions(lockstep=True, reaction=0.5).check(sc)
    with pytest.raises(ConfigError, match=r"--reaction must be in \[0, 1\)"):
        SitlOptions(reaction=1.5).check(sc)
    assert SitlOptions(lockstep=True).check(sc).wait_periods == REACTION
    assert SitlOptions(reaction=0.2).check(sc).wait_periods == 0.2
