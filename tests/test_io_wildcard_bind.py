"""``link.bind = "0.0.0.0"``: our Announce names the addresses the vehicles see us from, never
0.0.0.0 (DUNE's UDP transport streams to a node only at an ``imc+udp`` address of its Announce
that the node's datagrams come from: ``Transports/UDP/Node.hpp``, ``activate()``)."""

from __future__ import annotations

import asyncio

import imcpy
import pytest
from test_io_link import DEPLOY_ID, ORIGIN_DEG, Fake, _until

from mpcasv.config import ConfigError
from mpcasv.io.config import deploy_config_from_dict
from mpcasv.io.imc import udp_services
from mpcasv.io.link import ImcLink
from mpcasv.io.netcheck import announced_hosts, check_bindable
from mpcasv.io.simvehicle import Node
from mpcasv.io.transport import Clock


def _cfg(vehicles, bind="0.0.0.0"):
    return deploy_config_from_dict({
        "identity": {"id": DEPLOY_ID},
        "origin": {"lat_deg": ORIGIN_DEG[0], "lon_deg": ORIGIN_DEG[1]},
        "link": {"bind": bind, "port": 0, "announce_to": []},
        "vehicle": vehicles,
        "controller": {"name": "hybrid-single", "preset": "paper1-field"},
    })  # fmt: skip


def test_bound_to_the_wildcard_the_announce_names_the_address_the_vehicles_see():
    """Bound to 0.0.0.0 with both vehicles at 127.0.0.1: the Announce a vehicle receives
    names imc+udp://127.0.0.1:PORT/ (our data port), once, and no 0.0.0.0."""

    async def main():
        asv = await Fake("fake-asv", 0x2801, imcpy.SystemType.USV).open()
        auv = await Fake("fake-auv", 0x2811).open()
        cfg = _cfg([{"role": "asv", "id": 0x2801, "address": f"127.0.0.1:{asv.ep.address[1]}"},
                    {"role": "auv", "id": 0x2811,
                     "address": f"127.0.0.1:{auv.ep.address[1]}"}])  # fmt: skip
        link = ImcLink(cfg, Clock())
        try:
            await link.start()
            assert link.endpoint.address[0] == "0.0.0.0"
            port = link.endpoint.address[1]
            assert await _until(lambda: any(isinstance(m, imcpy.Announce) for m in asv.received))
            msg = next(m for m in asv.received if isinstance(m, imcpy.Announce))
            assert "0.0.0.0" not in msg.services
            assert udp_services(msg.services) == [("127.0.0.1", port)]
            assert msg.services == f"imc+udp://127.0.0.1:{port}/"
        finally:
            link.close()
            asv.close()
            auv.close()

    asyncio.run(main())


def test_announced_hosts_is_the_bound_address_unless_wildcard():
    assert announced_hosts("127.0.0.1", [("10.0.10.50", 6002)], "link.bind") == ["127.0.0.1"]
    assert announced_hosts("0.0.0.0", [("127.0.0.1", 6002), ("127.0.0.1", 6003)],
                           "link.bind") == ["127.0.0.1"]  # fmt: skip
    with pytest.raises(ConfigError, match="link.bind 0.0.0.0: no vehicle address"):
        announced_hosts("0.0.0.0", [], "link.bind")


def test_the_wildcard_with_a_vehicle_to_discover_is_refused_in_one_line():
    """Which local address a vehicle learnt from its Announce sees us from is not known when
    we first announce (and DUNE keeps the services of our first Announce): refused at load,
    naming link.bind and the vehicle."""
    with pytest.raises(ConfigError) as err:
        _cfg([{"role": "asv", "id": 0x2801, "address": "127.0.0.1:6002"},
              {"role": "auv", "name": "lauv-x"}])  # fmt: skip
    text = " ".join(ln.strip() for ln in str(err.value).splitlines()[1:])
    assert "link.bind: 0.0.0.0" in text and "lauv-x" in text
    assert len(str(err.value).splitlines()) == 2  # the heading and one problem
    _cfg([{"role": "asv", "id": 0x2801, "address": "127.0.0.1:6002"},
          {"role": "auv", "name": "lauv-x"}], bind="127.0.0.1")  # a concrete address: fine


def test_the_bind_hint_no_longer_suggests_the_wildcard():
    with pytest.raises(ConfigError) as err:
        check_bindable("192.0.2.1", 0, "link.bind")  # TEST-NET-1: no address of this host
    assert "0.0.0.0" not in str(err.value) and "vehicles' network" in str(err.value)


def test_the_sitl_answers_at_the_service_a_node_writes_from():
    """As DUNE's Node::activate: of several imc+udp services, the one the datagrams come
    from (it sent to the first one)."""
    node = Node(0x4001, "mpcasv-deploy", [("10.0.0.5", 6002), ("127.0.0.1", 6002)])
    assert node.dest == ("10.0.0.5", 6002)
    node.active = ("127.0.0.1", 6002)
    assert node.dest == ("127.0.0.1", 6002)


def test_the_sitl_bound_to_the_wildcard_announces_and_prints_reachable_addresses(tmp_path,
                                                                                 capsys):
    """``mpcasv sitl --bind 0.0.0.0``: each vehicle's Announce to a node on 127.0.0.1 names
    imc+udp://127.0.0.1:PORT/ (its data port, as the node sees it: netcheck.announced_hosts,
    the deploy's helper), and the printed ready line names reachable addresses, never
    0.0.0.0 (before: imc+udp://0.0.0.0:PORT/ and "0.0.0.0:PORT", where nobody can send)."""
    import json

    from test_io_sitl import ME, Node, _run, _until

    async def body(sitl):
        node = await Node().open()
        node.announce(("127.0.0.1", sitl.discovery.address[1]))
        for v in sitl.vehicles:
            assert await _until(lambda v=v: node.of(imcpy.Announce, v.id))
            services = {m.services for m in node.of(imcpy.Announce, v.id)}
            assert services == {f"imc+udp://127.0.0.1:{v.port}/"}, services
        node.send(imcpy.Heartbeat(), ("127.0.0.1", sitl.asv.port), dst=sitl.asv.id, src=ME)
        assert await _until(lambda: node.of(imcpy.EstimatedState, sitl.asv.id))
        # the datagrams come from the address the Announce named (DUNE's Node::activate)
        assert node.sources["EstimatedState"] == {("127.0.0.1", sitl.asv.port)}

    sitl = _run(tmp_path, body, duration=1000.0, bind="0.0.0.0")
    assert sitl.discovery.address[0] == "0.0.0.0"  # bound to the wildcard indeed
    out = capsys.readouterr().out
    ready = json.loads(next(ln for ln in out.splitlines() if ln.startswith('{"ready"')))["ready"]
    assert "0.0.0.0" not in json.dumps(ready)
    from mpcasv.io.netcheck import local_hosts  # (new with it)

    hosts = local_hosts("0.0.0.0")
    assert ready["hosts"] == hosts and "127.0.0.1" in hosts and "0.0.0.0" not in hosts
    first = hosts[0]  # another host's peers' address when this host has one (below)
    assert ready["discovery"] == f"{first}:{sitl.discovery.address[1]}"
    assert [v["address"] for v in ready["vehicles"]] == [f"{first}:{v.port}"
                                                         for v in sitl.vehicles]  # fmt: skip
    assert local_hosts("127.0.0.1") == ["127.0.0.1"]


def test_a_wildcard_bind_prints_the_address_other_hosts_reach_first(monkeypatch):
    """Bound to 0.0.0.0 (for peers on other hosts) the ready line's addresses were the
    loopback's, which another host cannot reach (a review): loopback comes last now."""
    import socket
    from types import SimpleNamespace

    from mpcasv.io import netcheck

    def addr(a):
        return SimpleNamespace(family=socket.AF_INET, address=a)

    monkeypatch.setattr(netcheck.psutil, "net_if_addrs", lambda: {
        "lo": [addr("127.0.0.1")], "eth0": [addr("10.0.10.7")], "wlan0": [addr("192.168.1.4")]})
    assert netcheck.local_hosts("0.0.0.0") == ["10.0.10.7", "192.168.1.4", "127.0.0.1"]
    monkeypatch.setattr(netcheck.psutil, "net_if_addrs", lambda: {"lo": [addr("127.0.0.1")]})
    assert netcheck.local_hosts("0.0.0.0") == ["127.0.0.1"]
