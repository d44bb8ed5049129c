"""Deploy configuration fields and replay options that were accepted and had no effect, or
an effect nobody was told of (session 25 audit): each now works, is refused in one line
(exit 2) naming it, or is stated.
"""

from __future__ import annotations

import pytest
from test_io_silent_options import _config, _deploy_refused

from mpcasv.io.config import deploy_config_from_dict

TCP_VEHICLES = [{"role": "asv", "id": 0x2801, "tcp": "127.0.0.1:6001"},
                {"role": "auv", "id": 0x2802, "tcp": "127.0.0.1:6002"}]  # fmt: skip


# --- 1. UDP-only [link] fields with link.transport = "tcp" ----------------------------------

@pytest.mark.parametrize("field, value", [
    ("port", 6010), ("announce_to", ["127.0.0.1:30100"]), ("announce_period", 5.0),
    ("discovery_ports", [30100]), ("discovery_group", "224.0.75.70"),
    ("discovery_bind", "127.0.0.1"),
])  # fmt: skip
def test_a_udp_only_link_field_with_tcp_is_refused(field, value, tmp_path, capsys):
    """With the TCP backseat the link binds no data port, sends no Announce and opens no
    discovery socket (ImcLink.start): these fields, written by the user, were loaded and
    never read. Refused at load naming the field and the transport; with UDP they load."""
    data = _config(vehicle=TCP_VEHICLES, link={"transport": "tcp", field: value})
    _deploy_refused(data, tmp_path, capsys, f"link.{field}", "link.transport = 'tcp'",
                    "transport = 'udp'")  # fmt: skip
    udp = _config(link={field: value})
    assert getattr(deploy_config_from_dict(udp).link, field) == (
        tuple(value) if isinstance(value, list) else value)  # fmt: skip


def test_tcp_with_the_fields_it_reads_loads_and_defaults_are_never_refused():
    """`bind` (the local address of the TCP connections), the timing and the plan fields
    are read with TCP; the UDP-only fields left at their defaults are not refused."""
    link = {"transport": "tcp", "bind": "127.0.0.1", "heartbeat_period": 0.5,
            "followref_timeout": 8.0, "reference_lead_m": 10.0}  # fmt: skip
    cfg = deploy_config_from_dict(_config(vehicle=TCP_VEHICLES, link=link))
    assert cfg.link.transport == "tcp" and cfg.link.port == 6002  # the default, unread
    from mpcasv.io.config import UDP_ONLY  # the refused fields are the ones tested above

    assert set(UDP_ONLY) == {"port", "announce_to", "announce_period", "discovery_ports",
                             "discovery_group", "discovery_bind"}  # fmt: skip


def test_several_udp_only_fields_are_named_together(tmp_path, capsys):
    data = _config(vehicle=TCP_VEHICLES, link={"transport": "tcp", "port": 0,
                                               "announce_to": []})  # fmt: skip
    _deploy_refused(data, tmp_path, capsys, "link.port, link.announce_to", "remove them")


def test_a_vehicle_udp_address_with_tcp_is_refused(tmp_path, capsys):
    """`[[vehicle]] address` (its IMC UDP service) with link.transport = 'tcp' was loaded and
    never used (every message goes over the vehicle's TCP stream); refused, as `tcp` is
    with UDP."""
    veh = [TCP_VEHICLES[0] | {"address": "127.0.0.1:6002"}, TCP_VEHICLES[1]]
    _deploy_refused(_config(vehicle=veh, link={"transport": "tcp"}), tmp_path, capsys,
                    "vehicle.address", "0x2801", "link.transport = 'udp'")  # fmt: skip
