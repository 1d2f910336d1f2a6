"""FreeRTPS nodes against hostile participants on 127.0.0.1: invalid and spoofed locators, the participant
limit and lease expiry. Real sockets send the SPDPs; the node must keep announcing and answering."""

from __future__ import annotations

import random
import socket
import time
from pathlib import Path

import pytest

from hilbench.bench.control import ControlClient
from hilbench.bench.profile import parse_profile
from hilbench.fakes.rtps_node.participant import LOCATOR_PORTS, MAX_REMOTES
from hilbench.protocols import rtps
from hilbench.pytest_plugin import wait_until
from tests.helpers.domains import free_domain

TALKER = {"name": "talker", "participant_index": 0, "topics": [
    {"name": "chatter", "type": "std_msgs/String", "direction": "pub", "rate_hz": 10, "value": "Hello"}]}


def _profile(domain: int) -> dict:
    return {"schema": 1, "endpoints": {"n": {"type": "udp", "protocol": "rtps", "domain_id": domain}},
            "devices": [TALKER]}


def spdp(prefix: bytes, domain: int, meta: tuple[str, int], user: tuple[str, int] | None = None,
         lease_s: int = 100) -> bytes:
    """An SPDP DATA(p) of participant ``prefix`` naming ``meta`` (and ``user``) as its unicast locators."""
    user = user or meta
    payload = rtps.spdp_payload(prefix, meta_port=meta[1], user_port=user[1], address=meta[0], domain_id=domain,
                                lease_s=lease_s)
    return rtps.message(prefix, rtps.data(rtps.ENTITYID_UNKNOWN, rtps.SPDP_WRITER, 1, payload,
                                          inline_qos=rtps.key_hash_qos(prefix + rtps.ENTITYID_PARTICIPANT)),
                        vendor_id=b"\x01\x10")


def udp(port: int = 0) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    return s


def spdp_numbers(sock: socket.socket, prefix: bytes, seconds: float, want: int = 1) -> list[int]:
    """Sequence numbers of the SPDPs participant ``prefix`` sends to ``sock``: ``want`` of them, or what
    came within ``seconds``."""
    out: list[int] = []
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0 and len(out) < want:
        sock.settimeout(left)
        try:
            data = sock.recv(65536)
        except TimeoutError:
            break
        m = rtps.parse_message(data)
        if m.guid_prefix == prefix:
            out += [s.fields["sn"] for s in m.submessages if s.fields and s.fields.get("writer_id") == rtps.SPDP_WRITER]
    return out


def test_an_spdp_with_port_70000_does_not_stop_the_nodes_announcements(hilbench_emulator, tmp_path: Path) -> None:
    domain = free_domain()
    profile = tmp_path / "hostile.toml"
    profile.write_text(f'schema = 1\n[endpoints.n]\ntype = "udp"\nprotocol = "rtps"\ndomain_id = {domain}\n'
                       '[[devices]]\nname = "talker"\nparticipant_index = 0\n'
                       'topics = [{ name = "chatter", type = "std_msgs/String", direction = "pub", rate_hz = 10 }]\n')
    bench = hilbench_emulator(profile)
    talker = bytes.fromhex(next(d for d in bench["devices"] if d["name"] == "talker")["guid_prefix"])
    node = ("127.0.0.1", rtps.ports(domain, 0)["metatraffic_unicast"])
    watcher = udp(rtps.ports(domain, 5)["metatraffic_unicast"])  # a peer index the node announces itself to
    attacker, newcomer = udp(), udp()
    try:
        assert spdp_numbers(watcher, talker, 3.0), "the node announced nothing before the attack"
        evil = spdp(b"\x01\x10" + bytes(10), domain, ("127.0.0.1", 70000))
        attacker.sendto(evil, node)
        after = spdp_numbers(watcher, talker, 5.0, want=2)  # one a second
        assert len(after) == 2, "the node stopped announcing itself"
        # A participant arriving now is still answered at once (its SPDP, then the node's SEDP).
        prefix = bytes(range(1, 13))
        newcomer.sendto(spdp(prefix, domain, newcomer.getsockname()), node)
        assert spdp_numbers(newcomer, talker, 5.0)
        status = ControlClient.from_manifest(bench["manifest_path"]).call("status", device="talker")["status"]
        assert status["counters"]["invalid_locators"] == 1
        assert status["participant"]["peers"] == [rtps.guid_text(prefix)]
    finally:
        for s in (watcher, attacker, newcomer):
            s.close()
    proc = bench["process"]
    proc.terminate()
    _, err = proc.communicate(timeout=10)
    assert "Traceback" not in err and "OverflowError" not in err, err


def _low_port_socket() -> socket.socket:
    """A UDP socket on a port below the RTPS port base (where the machine's services live)."""
    for port in random.sample(range(2000, LOCATOR_PORTS[0]), 50):
        try:
            return udp(port)
        except OSError:
            continue
    pytest.skip("no free UDP port below 7400")


def test_spoofed_locators_naming_other_ports_are_never_sent_to(hilbench_bench) -> None:
    domain = free_domain()
    b = hilbench_bench(parse_profile(_profile(domain), "n.toml"), port_state=False, tap=False)
    p = b.device("talker").participant
    node = ("127.0.0.1", rtps.ports(domain, 0)["metatraffic_unicast"])
    victim, attacker = _low_port_socket(), udp()
    victim.setblocking(False)
    try:
        attacker.sendto(spdp(bytes(range(20, 32)), domain, victim.getsockname()), node)
        wait_until(lambda: p.counters["unreachable"] == 1, 5)
        assert p.counters["locators_refused"] == 2 and not p.remotes
        ticks = p.counters["spdp_sent"]
        wait_until(lambda: p.counters["spdp_sent"] >= ticks + 9, 5)  # an announcement round later
        with pytest.raises(BlockingIOError):
            victim.recv(65536)
    finally:
        victim.close()
        attacker.close()


def test_remote_participants_are_bounded_and_expire_at_their_lease(hilbench_bench) -> None:
    domain = free_domain()
    b = hilbench_bench(parse_profile(_profile(domain), "n.toml"), port_state=False, tap=False)
    limits = next(d for d in b.manifest()["devices"] if d["name"] == "talker")["limits"]
    assert limits["participants"] == MAX_REMOTES and limits["locator_ports"] == [7400, 65535]
    p = b.device("talker").participant
    p.max_remotes = 3  # (the limit is MAX_REMOTES; three keep the test small)
    node = ("127.0.0.1", rtps.ports(domain, 0)["metatraffic_unicast"])
    peer = udp()
    try:
        for i in range(5):
            peer.sendto(spdp(bytes([0x42, i]) + bytes(10), domain, peer.getsockname(), lease_s=1), node)
        wait_until(lambda: p.counters["participants_refused"] == 2, 5)
        assert len(p.remotes) == 3 and p.counters["participants_discovered"] == 3
        # Silent for their one-second lease, they are forgotten (checked with each announcement round).
        wait_until(lambda: not p.remotes, 5)
        assert p.counters["participants_expired"] == 3
        peer.sendto(spdp(bytes([0x43]) + bytes(11), domain, peer.getsockname()), node)
        wait_until(lambda: len(p.remotes) == 1, 5)
        st = b.device("talker").status()
        assert st["counters"]["participants_expired"] == 3 and st["participant"]["limits"]["participants"] == 3
    finally:
        peer.close()
