"""A boolean in a configuration is true or false, never a string or a number: a preset's or
an override's ``course_control = "yes"`` (and ``1``, ``"off"``) was taken as a boolean and
the deploy prepared (found by a new-user test, session 29); so were a deploy
configuration's ``speed_feedback`` and a scenario's ``log_every_step``."""

from __future__ import annotations

import pytest

from mpcasv.config import ConfigError
from mpcasv.controllers import make_controller
from mpcasv.sim.scenario import scenario_from_dict

NOT_BOOLEANS = ["yes", "off", "true", 1, 0, 1.0]


@pytest.mark.parametrize("value", NOT_BOOLEANS)
def test_an_mpc_flag_that_is_not_a_boolean_is_refused(value):
    with pytest.raises(ConfigError, match="course_control"):
        make_controller("mpc-single", 1, "mpc-single", overrides={"course_control": value})


@pytest.mark.parametrize("value", [True, False])
def test_an_mpc_flag_that_is_a_boolean_is_taken(value):
    ctrl = make_controller("mpc-single", 1, "mpc-single", overrides={"course_control": value})
    assert ctrl.params.course_control is value


@pytest.mark.parametrize("value", ["yes", 1])
def test_a_deploy_flag_that_is_not_a_boolean_is_refused(tmp_path, value):
    from test_deploy_field import _mpc_cfg

    from mpcasv.io.config import deploy_config_from_dict

    data = _mpc_cfg(tmp_path)
    data["controller"]["speed_feedback"] = value
    with pytest.raises(ConfigError, match="speed_feedback"):
        deploy_config_from_dict(data)


@pytest.mark.parametrize("value", ["true", 1])
def test_a_scenario_flag_that_is_not_a_boolean_is_refused(value):
    data = {"name": "s", "duration": 10.0, "sim": {"log_every_step": value},
            "auv": [{"name": "a", "start": {"N": 0.0, "E": 0.0, "depth": 0.0},
                     "behaviour": {"loiter": {}}}]}  # fmt: skip
    with pytest.raises(ConfigError, match="log_every_step"):
        scenario_from_dict(data)
