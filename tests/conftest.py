"""Shared fixtures: the repository root, the shipped scenarios, Gretha's model and execution
level."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "experiments" / "scenarios"


@pytest.fixture(scope="session")
def scenarios_dir() -> Path:
    return SCENARIOS


@pytest.fixture(scope="session")
def model():
    """Gretha's vessel model (the shipped ``gretha`` vessel file)."""
    from mpcasv.models.params import load_vessel
    from mpcasv.models.vessel import VesselModel

    return VesselModel(load_vessel("gretha"))


@pytest.fixture(scope="session")
def shipped():
    """Gretha's shipped execution level (``mpcasv/data/execution/gretha.toml``)."""
    from mpcasv.control.params import load_execution

    return load_execution("gretha")
