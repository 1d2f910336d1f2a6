"""The FreeRTPS nodes among themselves (no third party): discovery on unicast 127.0.0.1, FreeRTPS's message
layout (INFO_TS + DATA, 60 + n bytes), echo, naming modes, the manifest, the bundled profile, port conflicts."""

from __future__ import annotations

import re
import socket

import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import ProfileError, load_profile, parse_profile
from hilbench.errors import UnavailableError
from hilbench.protocols import rtps
from hilbench.pytest_plugin import wait_until
from tests.helpers.domains import free_domain


def _profile(domain: int, naming: str = "ros2") -> dict:
    return {"schema": 1, "endpoints": {"n": {"type": "udp", "protocol": "rtps", "domain_id": domain,
                                             "naming": naming}},
            "devices": [
                {"name": "talker", "participant_index": 0, "topics": [
                    {"name": "chatter", "type": "std_msgs/String", "direction": "pub", "rate_hz": 50,
                     "value": "Hello"}]},
                {"name": "listener", "participant_index": 1, "topics": [
                    {"name": "chatter", "type": "std_msgs/String", "direction": "sub"},
                    {"name": "echo", "type": "std_msgs/String", "direction": "pub", "echo_of": "chatter"}]},
                {"name": "echo_listener", "participant_index": 2, "topics": [
                    {"name": "echo", "type": "std_msgs/String", "direction": "sub"}]},
            ]}


@pytest.fixture
def nodes(hilbench_bench):
    """Factory: the three nodes on a started bench in a free domain (``nodes(naming)``), stopped after."""
    return lambda naming="ros2": hilbench_bench(parse_profile(_profile(free_domain(), naming), "n.toml"),
                                                port_state=False, tap=False)


def test_nodes_discover_each_other_and_echo(nodes) -> None:
    b = nodes()
    listener, last = b.device("listener"), b.device("echo_listener")
    wait_until(lambda: listener.received["chatter"] >= 10 and last.received["echo"] >= 5, 10)
    assert {s["data"] for s in listener.samples["chatter"]} == {"Hello"}
    # The echo republishes every sample it got (in the net's thread, right when it arrives).
    wait_until(lambda: listener.published["echo"] == listener.received["chatter"], 2)
    talker = b.device("talker").participant
    assert {p.prefix for p in talker.remotes.values()} == {listener.guid_prefix, last.guid_prefix}
    assert talker.counters["non_loopback_locators"] == 0


def test_freertps_message_layout_and_sizes(nodes) -> None:
    b = nodes()
    seen: list[bytes] = []
    b.endpoint().medium.add_tap(lambda t, src, data, addr: seen.append(data) if src == "talker" else None)
    wait_until(lambda: any(len(d) == 70 for d in seen), 5)
    user = [d for d in seen if len(d) == 70]
    m = rtps.parse_message(user[0])
    assert [s.name for s in m.submessages] == ["INFO_TS", "DATA"] and not m.flags
    assert m.guid_prefix == bytes.fromhex("2C2F2C4D5901235100000000")  # 2C 2F + the MAC of index 0
    d = m.submessages[1].fields
    assert d["writer_id"] == b"\x00\x00\x01\x03" and d["payload"] == bytes.fromhex("00010000 06000000 48656C6C6F00")
    seconds = m.submessages[0].fields["seconds"]
    assert rtps.FREERTPS_EPOCH <= seconds < rtps.FREERTPS_EPOCH + 3600  # FreeRTPS's fake epoch + uptime


def test_manifest_entries(nodes) -> None:
    b = nodes()
    devs = {d["name"]: d for d in b.manifest()["devices"]}
    echo = devs["listener"]
    domain = echo["domain_id"]
    assert echo["participant_index"] == 1 and echo["ports"] == {
        "metatraffic_unicast": rtps.ports(domain, 1)["metatraffic_unicast"],
        "user_unicast": rtps.ports(domain, 1)["user_unicast"]}
    assert echo["topics"] == [
        {"name": "chatter", "dds_name": "rt/chatter", "type": "std_msgs/String",
         "dds_type": "std_msgs::msg::dds_::String_", "direction": "sub", "rate_hz": 0.0, "reliable": False},
        {"name": "echo", "dds_name": "rt/echo", "type": "std_msgs/String", "dds_type": "std_msgs::msg::dds_::String_",
         "direction": "pub", "rate_hz": 0.0, "reliable": False, "echo_of": "chatter"}]
    assert devs["talker"]["topics"][0]["rate_hz"] == 50.0
    ep = b.manifest()["endpoints"][0]
    assert (ep["type"], ep["protocol"], ep["domain_id"], ep["naming"]) == ("udp", "rtps", domain, "ros2")


def test_legacy_naming_uses_bare_names(nodes) -> None:
    b = nodes("legacy")
    listener = b.device("listener")
    wait_until(lambda: listener.received["chatter"] >= 3, 10)
    assert listener.readers["chatter"].topic == "chatter"


def test_a_taken_port_is_a_one_line_bench_error() -> None:
    domain = free_domain()
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", rtps.ports(domain, 0)["metatraffic_unicast"]))
    try:
        with pytest.raises(UnavailableError) as err:  # exit status 1, one line naming what to change
            Bench(parse_profile(_profile(domain), "n.toml")).start()
        port = rtps.ports(domain, 0)["metatraffic_unicast"]
        assert str(err.value).startswith(f"n.toml: endpoint 'n': cannot listen on RTPS port 127.0.0.1:{port}: "
                                         "Address already in use (node 'talker': domain "), err.value
        assert str(err.value).endswith("; change endpoints.n.domain_id in the profile, or --set "
                                       "n.domain_id=VALUE"), err.value
    finally:
        blocker.close()


def test_bundled_profile() -> None:
    p = load_profile("freertps")
    ep = p.endpoints["nodes"]
    assert ep.options["domain_id"] == 42 and ep.options["naming"] == "ros2"
    assert [d.name for d in p.devices] == ["talker", "setpoint", "echo"]
    assert p.devices[1].topics[0]["value"] == 1638


@pytest.mark.parametrize("topics, key, expected", [
    ([{"name": "a", "type": "std_msgs/Nope", "direction": "pub"}], "topics[0].type", "unknown message type"),
    ([{"name": "a", "type": "std_msgs/String", "direction": "both"}], "topics[0].direction", "expected one of"),
    ([{"name": "a", "type": "std_msgs/String", "direction": "pub", "echo_of": "b"}], "topics[0].echo_of",
     "subscribed topic"),
    ([{"name": "a", "type": "std_msgs/String", "direction": "pub", "rate_hz": -1}], "topics[0].rate_hz",
     "expected a number"),
])
def test_profile_errors_name_the_key(topics, key, expected) -> None:
    prof = {"schema": 1, "endpoints": {"n": {"type": "udp", "protocol": "rtps"}},
            "devices": [{"name": "x", "topics": topics}]}
    with pytest.raises(ProfileError, match=re.escape(f"n.toml: devices[0].{key}: ") + f".*{expected}"):
        parse_profile(prof, "n.toml")


def test_two_nodes_on_one_index_is_a_profile_error() -> None:
    prof = {"schema": 1, "endpoints": {"n": {"type": "udp", "protocol": "rtps"}},
            "devices": [{"name": "a", "mac": "02:00:00:00:00:01", "topics": [
                {"name": "t", "type": "std_msgs/String", "direction": "sub"}]},
                {"name": "b", "mac": "02:00:00:00:00:02", "topics": [
                    {"name": "t", "type": "std_msgs/String", "direction": "sub"}]}]}
    with pytest.raises(ProfileError, match=r"participant_index: participant index 0 is taken on endpoint 'n' by devices\[0\] \('a'\)"):
        parse_profile(prof, "n.toml")
