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

import pytest
from pydantic import model_validator

from mpcasv.config import ConfigError, FieldError, Prob, between, frozen


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
