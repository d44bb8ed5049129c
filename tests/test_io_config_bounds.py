"""A field engineer's deploy limits that passed ``mpcasv deploy CONFIG --prepare`` with exit 0
(timeouts of 1e9 s and 1e-4 s, speeds of 1e-9 and 1e9 m/s, slacks and margins of 1e12, two
vehicles at one address, a discovery port twice or 0, IMC id 0, an empty plan id): each is
refused in one line naming the file, the field and why (exit 2), and the bounds themselves
load."""

from __future__ import annotations

import pytest
from test_io_bad_input import _deploy_config, _exit_code, _refused


def _edit(path, *edits):
    """Apply ``(after, line)`` edits: insert ``line`` after the first line equal to ``after``
    (``None``: append at the end), or ``(old, new)`` with ``old`` a whole line to replace
    (marked ``"=" + old``)."""
    lines = path.read_text().splitlines()
    for where, line in edits:
        if where is None:
            lines.append(line)
        elif where.startswith("="):
            lines[lines.index(where[1:])] = line
        else:
            lines.insert(lines.index(where) + 1, line)
    path.write_text("\n".join(lines) + "\n")


ADDRESSED = [('name = "sitl-asv"', 'address = "127.0.0.1:6002"'),
             ('name = "sitl-auv"', 'address = "127.0.0.1:6002"'),
             ("=discovery_ports = []", "")]  # fmt: skip

# (edits of the shipped rehearsal configuration, words the one line must hold)
BAD = {
    "plan_done_timeout 1e9": ([("[link]", "plan_done_timeout = 1e9")],
                              ["link.plan_done_timeout", "1e+09 s", "[0.1, 60] s", "MANDONE"]),
    "plan_start_timeout 1e9": ([("[link]", "plan_start_timeout = 1e9")],
                               ["link.plan_start_timeout", "1e+09 s", "[1, 60] s"]),
    "plan_start_timeout 1e-4": ([("[link]", "plan_start_timeout = 0.0001")],
                                ["link.plan_start_timeout", "0.0001 s", "re-sends"]),
    "max_distance_m 1e-9": ([("[watchdog]", "max_distance_m = 1e-9")],
                            ["watchdog.max_distance_m", "1e-09 m", "[100, 3.024e+06] m"]),
    "asv_speed_max 1e-9": ([("[watchdog]", "asv_speed_max = 1e-9")],
                           ["watchdog.asv_speed_max", "1e-09 m/s", "[1, 20] m/s"]),
    "auv_speed_max 1e9": ([("=auv_speed_max = 2.0", "auv_speed_max = 1e9")],
                          ["watchdog.auv_speed_max", "1e+09 m/s", "[0.1, 5] m/s", "fastest AUV"]),
    "clock_slack_s 1e12": ([("[watchdog]", "clock_slack_s = 1e12")],
                           ["watchdog.clock_slack_s", "1e+12 s", "[0.5, 60] s"]),
    "jump_margin_m 1e12": ([("[watchdog]", "jump_margin_m = 1e12")],
                           ["watchdog.jump_margin_m", "1e+12 m", "[0, 1000] m"]),
    "clock_step_states 100000": ([("[watchdog]", "clock_step_states = 100000")],
                                 ["watchdog.clock_step_states", "100000", "[2, 20]"]),
    "reference_lead_m 1e9": ([("=reference_lead_m = 20.0", "reference_lead_m = 1e9")],
                             ["link.reference_lead_m", "1e+09 m", "[0, 1000] m"]),
    "command_max 250": ([(None, "[speed]"), (None, "command_max = 250.0")],
                        ["speed.command_max", "250 m/s", "(0, 10] m/s"]),
    "same address": (ADDRESSED, ["vehicle[1].address", "127.0.0.1:6002", "sitl-asv"]),
    "discovery port twice": ([("=discovery_ports = []", "discovery_ports = [30102, 30102]")],
                             ["link.discovery_ports", "30102 given twice"]),
    "discovery port 0": ([("=discovery_ports = []", "discovery_ports = [0]")],
                         ["link.discovery_ports", "0 (a port the OS picks)", "30100-30104"]),
    "identity id 0": ([("=id = 0x4001", "id = 0")], ["identity.id", "0x0000", "'announce'"]),
    "empty plan_id": ([("[link]", 'plan_id = ""')], ["link.plan_id", "''", "plan id is 1-64"]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_deploy_refuses_a_limit_out_of_its_bounds_in_one_line(case, tmp_path, capsys):
    edits, words = BAD[case]
    path = _deploy_config(tmp_path)
    _edit(path, *edits)
    _refused(["deploy", path, "--quiet", "--prepare"], capsys, str(path), *words)
    assert not (tmp_path / "log").exists()


def test_deploy_takes_the_limits_at_their_bounds(tmp_path, capsys):
    """Every new bound is inclusive (command_max's lower one excepted: open); two vehicles at
    different ports of one host, and the rehearsal's 'discovery_ports = []', are fine."""
    for edits in (
        [("[link]", "plan_done_timeout = 0.1"), ("[link]", "plan_start_timeout = 60.0"),
         ("=reference_lead_m = 20.0", "reference_lead_m = 1000.0"),
         ("[link]", 'plan_id = "a.B-9_x"'), ("=id = 0x4001", "id = 1"),
         ("[watchdog]", "max_distance_m = 100.0"), ("[watchdog]", "asv_speed_max = 20.0"),
         ("=auv_speed_max = 2.0", "auv_speed_max = 0.1"), ("[watchdog]", "clock_slack_s = 0.5"),
         ("[watchdog]", "jump_margin_m = 0.0"), ("[watchdog]", "clock_step_states = 20"),
         (None, "[speed]"), (None, "command_max = 10.0")],
        [("[link]", "plan_done_timeout = 60.0"), ("[link]", "plan_start_timeout = 1.0"),
         ("=reference_lead_m = 20.0", "reference_lead_m = 0.0"), ("=id = 0x4001", "id = 0xFFFE"),
         ("[watchdog]", "max_distance_m = 3024000.0"), ("[watchdog]", "asv_speed_max = 1.0"),
         ("=auv_speed_max = 2.0", "auv_speed_max = 5.0"), ("[watchdog]", "clock_slack_s = 60.0"),
         ("[watchdog]", "jump_margin_m = 1000.0"), ("[watchdog]", "clock_step_states = 2"),
         ('name = "sitl-asv"', 'address = "127.0.0.1:6002"'),
         ('name = "sitl-auv"', 'address = "127.0.0.1:6003"'), ("=discovery_ports = []", "")],
    ):  # fmt: skip
        path = _deploy_config(tmp_path)
        _edit(path, *edits)
        assert _exit_code(["deploy", path, "--quiet", "--prepare"]) == 0, capsys.readouterr().err
