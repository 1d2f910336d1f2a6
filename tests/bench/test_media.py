"""The control channel's ``media``: every bench reports its lines' and buses' kind, pacing and counters."""

from __future__ import annotations

import dynamixel_sdk as sdk

from hilbench.bench.bench import Bench
from hilbench.bench.control import BENCH_COMMANDS, ControlClient, ControlServer
from hilbench.bench.profile import load_profile

IDS = list(range(1, 21))


def test_a_paced_line_reports_how_late_it_delivered(hilbench_emulator):
    """A bench with no family commands (the Wolfgang servo bus) still serves the channel; after an official
    SDK's Sync Reads, the line counts each delivery it timed against its wire model."""
    bench = hilbench_emulator("wolfgang", "--paced")
    control = ControlClient(bench["control"])
    before = control.media()["dxl"]
    assert before["kind"] == "serial" and before["paced"] is True
    assert before["scheduling"].startswith(("SCHED_FIFO", "SCHED_OTHER"))
    assert before["cpu_latency"] == "0 us" or before["cpu_latency"].startswith("not ")  # root: idle CPUs poll
    assert bench["endpoints"][0]["cpu_latency"] == before["cpu_latency"]  # the manifest says it too

    port = sdk.PortHandler(bench["endpoints"][0]["path"])
    assert port.openPort() and port.setBaudRate(2_000_000)
    ph = sdk.PacketHandler(2.0)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    for i in IDS:
        reader.addParam(i)
    cycles = 5
    for _ in range(cycles):
        assert reader.txRxPacket() == sdk.COMM_SUCCESS
    port.closePort()

    after = control.media()["dxl"]["stats"]
    # each Sync Read: the request and twenty statuses, every one timed against the model
    assert after["late_count"] - before["stats"]["late_count"] >= cycles * (1 + len(IDS))
    assert after["transmissions"] - before["stats"]["transmissions"] >= cycles * (1 + len(IDS))
    assert after["late_total"] >= before["stats"]["late_total"] >= 0.0
    assert after["late_max"] >= 0.0 and after["late_over_1ms"] <= after["late_count"]
    assert sum(after["by_source"].values()) == after["bytes"]


def test_every_kind_of_medium_answers(tmp_path):
    """Serial and CAN benches in one process: ``media`` names each endpoint's medium with its counters and
    what its thread runs under; an unpaced line never runs under SCHED_FIFO."""
    profile = tmp_path / "mixed.toml"
    profile.write_text(
        'schema = 1\n'
        '[endpoints.arm]\nprotocol = "dynamixel"\nbaud = 1_000_000\n'
        '[[devices]]\nendpoint = "arm"\nmodel = "XL430-W250"\nids = [1]\n'
        '[endpoints.can]\ntype = "can"\nprotocol = "can"\nbitrate = 500_000\n'
        '[[devices]]\nendpoint = "can"\nmodel = "stm32f767-rover-canopen"\nname = "rover"\nnode_id = 2\n'
    )
    with Bench(load_profile(profile)) as bench:
        server = ControlServer(bench)
        try:
            reply = server.handle(b'{"cmd": "media"}')
            unknown = server.handle(b'{"cmd": "nosuch"}')
        finally:
            server.close()
    assert reply["ok"] is True
    media = reply["media"]
    assert media["arm"]["kind"] == "serial" and media["arm"]["paced"] is False
    assert media["arm"]["scheduling"] == "SCHED_OTHER" and "cpu_latency" not in media["arm"]
    assert {"transmissions", "bytes", "late_count", "late_total", "late_max"} <= set(media["arm"]["stats"])
    assert media["can"]["kind"] == "can" and {"frames", "bits", "error_frames"} <= set(media["can"]["stats"])
    assert media["can"]["scheduling"] == "SCHED_OTHER"  # (every medium's thread says what it runs under)
    assert "media" in BENCH_COMMANDS and "media" in unknown["error"]


def test_a_paced_can_bus_says_in_the_manifest_whether_idle_cpus_stay_awake(tmp_path):
    """The bus's thread makes the request; the bench's start waits for it, so the manifest has the answer."""
    profile = tmp_path / "can.toml"
    profile.write_text(
        'schema = 1\n'
        '[endpoints.can]\ntype = "can"\nprotocol = "can"\nbitrate = 500_000\n'
        '[[devices]]\nendpoint = "can"\nmodel = "stm32f767-rover-canopen"\nname = "rover"\nnode_id = 2\n'
    )
    with Bench(load_profile(profile), paced=True) as bench:
        entry = bench.manifest()["endpoints"][0]
        latency = bench.endpoint("can").medium.cpu_latency
    assert entry["paced"] is True
    assert latency == "0 us" or latency.startswith("not ")
    assert entry["cpu_latency"] == latency
