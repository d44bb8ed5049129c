"""Paths inside configuration files are resolved relative to the file that names them
(issue 13, Deliver 3), whatever the working directory."""

from __future__ import annotations

import shutil
import textwrap
from pathlib import Path

import pytest
from shared_data import CASES

from mpcasv.cli import main
from mpcasv.config import ConfigError
from mpcasv.experiments.suite import expand
from mpcasv.sim.scenario import load_scenario
from mpcasv.sim.world import build_plant

VESSELS = CASES / "vessels"


@pytest.fixture
def otter_case(tmp_path, monkeypatch):
    """Case folder ``relative-vessel-path``: ``vessels/case3-otter.toml`` says
    ``vessel = "otter.toml"``; both copied into a folder, the working directory elsewhere."""
    if not VESSELS.is_dir():
        pytest.skip(f"{VESSELS} not available")
    folder = tmp_path / "vessels"
    folder.mkdir()
    for name in ("case3-otter.toml", "otter.toml"):
        shutil.copy(VESSELS / name, folder / name)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    return folder / "case3-otter.toml"


def test_relative_vessel_path_is_resolved_against_the_scenario_folder(otter_case):
    # case folder: relative-vessel-path (failed with "unknown vessel 'otter.toml'" from elsewhere)
    sc = load_scenario(otter_case)
    assert Path(sc.asv.vessel) == (otter_case.parent / "otter.toml").resolve()
    model = build_plant(sc)[0]
    assert model.params.name == "otter"  # the Otter is integrated, not Gretha


def test_relative_vessel_path_case_simulates_from_another_directory(otter_case, tmp_path):
    # case folder: relative-vessel-path, the command of its README (exit 2 before the fix)
    out = tmp_path / "run"
    assert main(["simulate", str(otter_case), "--out", str(out), "--quiet", "--no-plots"]) == 0
    assert (out / "metrics.json").is_file()


def test_a_missing_relative_vessel_file_is_refused_naming_the_scenario(otter_case, capsys):
    (otter_case.parent / "otter.toml").unlink()
    with pytest.raises(ConfigError) as err:
        load_scenario(otter_case)
    msg = str(err.value)
    assert "asv.vessel" in msg and str(otter_case) in msg
    assert str(otter_case.parent / "otter.toml") in msg  # where it looked
    assert main(["simulate", str(otter_case), "--out", "x", "--quiet", "--no-plots"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_a_shipped_vessel_name_is_not_taken_as_a_path(otter_case):
    text = otter_case.read_text().replace('vessel = "otter.toml"', 'vessel = "gretha"')
    otter_case.write_text(text)
    assert load_scenario(otter_case).asv.vessel == "gretha"


def test_suite_paths_are_relative_to_the_suite_file(otter_case, tmp_path):
    """A suite in one folder names a scenario and a preset in others (relative paths); the
    scenario names its vessel relative to itself; expanded from a third working directory."""
    suites = tmp_path / "suites"
    (suites / "presets").mkdir(parents=True)
    shutil.copy(Path(__file__).parents[1] / "mpcasv/data/presets/paper1-field.toml",
                suites / "presets" / "mine.toml")  # fmt: skip
    (suites / "s.toml").write_text(textwrap.dedent("""
        name = "s"
        scenarios = ["../vessels/case3-otter.toml"]
        seeds = [0]
        [[controllers]]
        label = "hybrid"
        name = "hybrid-single"
        preset = "presets/mine.toml"
    """))
    (job,) = expand(suites / "s.toml").jobs
    assert job.scenario_path == str(otter_case.resolve())
    assert job.preset == str((suites / "presets" / "mine.toml").resolve())
