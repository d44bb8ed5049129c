"""One vessel per run (issue 13 item 3): the scenario's boat is the one the simulator integrates
and the MPC plans with; a preset that names another is refused in one line; ``run.json``
records the vessel's name and parameter hash; paths in a preset are relative to the preset.

Case folder: /work/shared/cases/mpc-ignores-scenario-vessel (with ../vessels/case3-otter.toml
and otter.toml): the MPC planned on Gretha while the simulator integrated the Otter.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from shared_data import CASES

from mpcasv.cli import main
from mpcasv.config import DATA_DIR, ConfigError
from mpcasv.controllers import Boat, check_boat, load_preset, make_controller, parameter_hash
from mpcasv.sim.scenario import load_scenario
from mpcasv.sim.world import build_plant

VESSELS = CASES / "vessels"  # used by mpc-ignores-scenario-vessel

pytestmark = pytest.mark.skipif(not VESSELS.is_dir(), reason=f"{VESSELS} not present")


@pytest.fixture
def otter_case(tmp_path, monkeypatch):
    """The case's scenario and vessel copied into a temporary folder (the case is read-only);
    the working directory is that folder, as in the case's README (``cd ../vessels``)."""
    for name in ("case3-otter.toml", "otter.toml"):
        shutil.copy(VESSELS / name, tmp_path / name)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_mpc_ignores_scenario_vessel_case_the_mpc_plans_with_the_simulated_boat(otter_case,
                                                                              monkeypatch):
    """mpc-ignores-scenario-vessel: with the Otter in the scenario, the MPC's model is the
    Otter's (T_max 239.36 N, u_max 3.086 m/s), equal to the simulator's, not Gretha's. The
    problem is what is checked, not its solver: building fatrop on the uncompiled functions
    took 23 s of the test's 29 (compiling them for the Otter, longer), so it is not built."""
    import mpcasv.mpc.controller as mpc_controller

    sc = load_scenario(otter_case / "case3-otter.toml")
    boat = Boat.of_scenario(sc)
    solvers = []
    monkeypatch.setattr(mpc_controller, "make_solver", lambda ocp, *a, **k: solvers.append(ocp))
    monkeypatch.setattr(mpc_controller, "_OCP_CACHE", {})  # no solver-less entry left behind
    ctrl = make_controller("mpc-single", 1, "mpc-single", {"solver.compiled": False}, boat=boat)
    assert solvers == [ctrl.ocp]  # the controller's solver would have been built for it
    model, ep, _ = build_plant(sc)  # what the simulator integrates
    assert ctrl.ocp.vessel == model.params
    assert ctrl.ocp.execution == ep
    assert (ctrl.ocp.vessel.name, ctrl.ocp.vessel.T_max, ctrl.ocp.vessel.u_max) == (
        "otter", 239.36, 3.086)  # fmt: skip
    assert list(ctrl.ocp.model.p) == list(model.p)


def test_a_preset_naming_another_vessel_is_refused_in_one_line(otter_case):
    """A preset that names Gretha, in a run whose boat is the Otter: refused, naming the
    preset file and both parameter hashes."""
    preset = otter_case / "mpc-gretha.toml"
    text = (DATA_DIR / "presets" / "mpc-single.toml").read_text()
    preset.write_text('vessel = "gretha"\n' + text)
    boat = Boat.load(otter_case / "otter.toml")
    with pytest.raises(ConfigError) as err:
        make_controller("mpc-single", 1, preset, boat=boat)
    msg = str(err.value)
    assert "\n" not in msg
    assert str(preset) in msg and "vessel = 'gretha'" in msg and "'otter'" in msg
    assert parameter_hash(boat.vessel) in msg
    # the same preset in a Gretha run is accepted (same parameters, whatever the file name)
    check_boat(load_preset("mpc-single", preset), Boat.load("gretha"), str(preset))


def test_paths_in_a_preset_are_relative_to_the_preset_file(otter_case, tmp_path_factory,
                                                            monkeypatch):  # fmt: skip
    """``vessel = "otter.toml"`` in a preset means the file beside the preset, from any
    working directory (case relative-vessel-path, for presets)."""
    preset = otter_case / "mpc-otter.toml"
    text = (DATA_DIR / "presets" / "mpc-single.toml").read_text()
    preset.write_text('vessel = "otter.toml"\n' + text)
    monkeypatch.chdir(tmp_path_factory.mktemp("elsewhere"))
    params = load_preset("mpc-single", preset)
    assert Path(params.vessel) == otter_case / "otter.toml"
    check_boat(params, Boat.load(otter_case / "otter.toml"), str(preset))  # same boat: fine
    with pytest.raises(ConfigError, match="one vessel per run"):
        check_boat(params, Boat.load("gretha"), str(preset))


def test_run_json_records_the_vessel_and_its_parameter_hash(otter_case):
    out = otter_case / "run"
    rc = main(["simulate", str(otter_case / "case3-otter.toml"), "--controller", "goto",
               "--out", str(out), "--quiet", "--no-plots"])  # fmt: skip
    assert rc == 0
    info = json.loads((out / "run.json").read_text())
    otter = Boat.load(otter_case / "otter.toml")
    assert info["boat"]["vessel"] == "otter"
    assert info["boat"]["vessel_sha256"] == parameter_hash(otter.vessel)
    assert info["boat"]["vessel_sha256"] != parameter_hash(Boat.load("gretha").vessel)
    assert info["boat"]["execution_sha256"] == parameter_hash(otter.execution)
