"""Profiles from CAN captures (issue 27): the mecarover-can bench recorded as python-can logs while the canopen
package drives it, back as recorded nodes; silent nodes; damaged logs."""

from __future__ import annotations

import json
import time
import tomllib

import canopen
import pytest

from hilbench.bench import Bench
from hilbench.bench.capture_profile import check_profile_text
from hilbench.cli import main
from hilbench.protocols import board_can as bc
from hilbench.protocols import canopen as co
from hilbench.pytest_plugin import wait_until
from tests.helpers.recording import infer_file, recording

canopen.Network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.0
UPLOADS = ((0x1000, 0), (0x1018, 1), (0x1018, 2), (0x1018, 3), (0x1017, 0), (0x1008, 0))


def _drive(bench, seconds: float = 1.2, *, ask_node: int | None = None) -> dict[tuple[int, int], bytes]:
    """What the rover's host software does: wait for the node, read its identity over SDO, start it, send
    velocity setpoints every 50 ms and read the odometry now and then. Returns the SDO values read."""
    net = canopen.Network(bench.endpoint("can").port.open_bus())
    net.connect()
    node = canopen.RemoteNode(2, canopen.ObjectDictionary())
    net.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 1.0
    read = {}
    try:
        wait_until(lambda: bench.family("canopen").node(2).state != co.BOOTUP)
        time.sleep(0.1)
        for index, sub in UPLOADS:
            read[(index, sub)] = node.sdo.upload(index, sub)
        if ask_node is not None:  # a node the host expects, which is not on the bus
            other = canopen.RemoteNode(ask_node, canopen.ObjectDictionary())
            net.add_node(other)
            other.sdo.RESPONSE_TIMEOUT = 0.05
            with pytest.raises(canopen.SdoCommunicationError):
                other.sdo.upload(0x1000, 0)
        node.nmt.send_command(co.NMT_START)
        end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < end:
            net.send_message(0x202, bc.build_setpoint(100.0, 0.0, 0.0, k))
            k += 1
            time.sleep(0.05)
    finally:
        net.disconnect()
    return read


@pytest.fixture(scope="module")
def rover_log(tmp_path_factory):
    """The mecarover-can bench recorded as a candump log (``hilbench record``'s CAN format)."""
    path = tmp_path_factory.mktemp("can") / "rover.log"
    bench = Bench("mecarover-can").start()
    try:
        with recording(bench.endpoint("can"), path):
            read = _drive(bench, ask_node=9)
    finally:
        bench.stop()
    return path, read


def test_round_trip_mecarover_can(rover_log):
    path, read = rover_log
    draft, facts, text = infer_file(path, baud=500_000)
    data = tomllib.loads(text)
    assert data["endpoints"]["can"]["bitrate"] == 500_000
    (node,) = data["devices"]  # node 9 never answered: a comment
    assert (node["model"], node["node_id"], node["heartbeat_ms"], node["autostart"]) == ("recorded-node", 2, 1000,
                                                                                        False)
    cfg = bc.BoardCanConfig()
    periods = {p.cob_id(2): cfg.periods_ms[p.key] for p in bc.PDOS if p.kind == "tpdo"}
    got = {t["cob_id"]: t for t in node["tpdos"]}
    assert set(got) == set(periods)  # every TPDO of the board, with its period
    for cob, period in periods.items():
        assert abs(got[cob]["period_ms"] - period) <= max(2, period // 10), (hex(cob), got[cob])
    objects = {(o["index"], o["subindex"]): bytes.fromhex(o["data"]) for o in node["objects"]}
    for key, value in read.items():
        assert objects[key] == value, key  # the SDO values the host read, byte for byte
    assert "asked but never answering: node 9" in draft.seen
    assert any(line.startswith("NMT start to node 2 at") for line in draft.pattern)
    assert any(line.startswith("RPDO 0x202: ") for line in draft.pattern)
    assert "# node 9: asked" in text and "# model        = \"recorded-node\"" in text


def test_round_trip_verify(rover_log, tmp_path, capsys):
    path, _ = rover_log
    out = tmp_path / "rover.toml"
    code = main(["profiles", "from-capture", str(path), "--baud", "500000", "-o", str(out), "--verify", "--json",
                 "--min-ratio", "0.95"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0, doc
    report = doc["verify"]
    assert report["ratio"] >= 0.95 and report["matched_content"] >= len(UPLOADS), report
    # every TPDO stream and the SDO answers: counted as replies
    assert report["replies"] >= len(UPLOADS) + 4


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".trc", ".csv", ".log.gz", ".asc.gz"])
def test_every_log_format_hilbench_records_gives_the_same_node(rover_log, tmp_path, suffix):
    """The recording in each python-can format ``hilbench record`` writes (its CAN recorder, python-can's own
    writers) reads back as the same node: heartbeat, TPDOs and the SDO values the host read."""
    _, read = rover_log
    other = _converted(rover_log, tmp_path, suffix)
    _, facts, text = infer_file(other, baud=500_000)
    assert facts.protocol == "can"
    (node,) = tomllib.loads(text)["devices"]
    assert (node["node_id"], node["heartbeat_ms"], len(node["tpdos"])) == (2, 1000, 4), suffix
    objects = {(o["index"], o["subindex"]): bytes.fromhex(o["data"]) for o in node["objects"]}
    assert all(objects[key] == value for key, value in read.items()), suffix


def test_the_canopen_package_reads_the_generated_bench_under_hilbench_emulate(rover_log, tmp_path, capsys,
                                                                             hilbench_emulator, monkeypatch):
    """The generated profile, unchanged, under ``hilbench emulate`` (another process), read by the host's own
    client over the bench's socketcand server: the SDO uploads return what the recorded node returned, and once
    started the node sends its TPDOs at the captured periods."""
    import can

    # (the socketcand bus is shut after its notifier thread stopped reading it, not under it)
    monkeypatch.setattr(canopen.Network, "NOTIFIER_SHUTDOWN_TIMEOUT", 2.0)
    path, read = rover_log
    out = tmp_path / "rover.toml"
    assert main(["profiles", "from-capture", str(path), "--baud", "500000", "-o", str(out)]) == 0
    capsys.readouterr()
    manifest = hilbench_emulator(str(out))
    s = manifest["endpoints"][0]["socketcand"]
    net = canopen.Network(can.Bus(interface="socketcand", host=s["host"], port=s["port"], channel=s["channel"]))
    net.connect()
    try:
        node = canopen.RemoteNode(2, canopen.ObjectDictionary())
        net.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 1.0
        # as a host does: the node answers once it has booted (its boot-up or a heartbeat says so; an upload sent
        # while it boots goes unanswered, as on the recorded bus)
        node.nmt.wait_for_heartbeat(timeout=3.0)
        assert {key: node.sdo.upload(*key) for key in read} == read
        times: dict[int, list[float]] = {0x182: [], 0x482: []}
        for cob, got in times.items():
            net.subscribe(cob, lambda _cob, _data, ts, got=got: got.append(ts))
        node.nmt.send_command(co.NMT_START)
        wait_until(lambda: len(times[0x482]) >= 6 and len(times[0x182]) >= 20, timeout=5)
    finally:
        net.disconnect()
    for cob, period in ((0x182, 0.020), (0x482, 0.100)):
        gaps = sorted(b - a for a, b in zip(times[cob], times[cob][1:], strict=False))
        assert abs(gaps[len(gaps) // 2] - period) <= period / 4, (hex(cob), gaps)


def test_keep_silent_makes_a_silent_node(rover_log):
    path, _ = rover_log
    _, _, text = infer_file(path, baud=500_000, keep_silent=True)
    nodes = {d["node_id"]: d for d in tomllib.loads(text)["devices"]}
    assert nodes[9]["faults"] == {"silent": True}
    profile = check_profile_text(text)
    with Bench(profile).start() as bench:
        assert bench.family("canopen").node(9).faults["silent"] is True


def test_a_truncated_log_gives_what_could_be_read(rover_log, tmp_path):
    path, _ = rover_log
    lines = path.read_text().splitlines(keepends=True)
    cut = tmp_path / "cut.log"
    cut.write_text("".join(lines[: len(lines) // 2]) + lines[len(lines) // 2][:9])  # killed mid-line
    draft, _, text = infer_file(cut, baud=500_000)
    assert tomllib.loads(text)["devices"][0]["node_id"] == 2
    assert "capture: truncated: the last line has no end (the recording was cut off): skipped" in draft.unread, \
        draft.unread


def test_a_damaged_log_is_read_past_its_bad_lines(rover_log, tmp_path):
    """Lines that are no frame (noise, a hex digit gone) are skipped and counted; what follows them is read."""
    path, read = rover_log
    lines = path.read_text().splitlines(keepends=True)
    lines[3] = "\x00\x7fgarbage (12.5) can0\n"
    lines[5] = lines[5].replace("#", "#Z", 1)
    damaged = tmp_path / "damaged.log"
    damaged.write_text("".join(lines))
    draft, _, text = infer_file(damaged, baud=500_000)
    assert "capture: 2 line(s) that are no candump frame skipped (the first: line 4)" in draft.unread, draft.unread
    (node,) = tomllib.loads(text)["devices"]
    assert len(node["tpdos"]) == 4  # the PDOs long after the damage were read


def test_a_hilbench_capture_of_the_can_bus(tmp_path):
    """``hilbench record`` of a CAN bench into its own capture format reads the same way as a python-can log."""
    bench = Bench("mecarover-can").start()
    try:
        with recording(bench.endpoint("can"), tmp_path / "rover.hbcap") as path:
            read = _drive(bench, 0.5)
    finally:
        bench.stop()
    draft, facts, text = infer_file(path)
    assert facts.protocol == "can" and facts.baud == 500_000  # the capture says its bitrate
    (node,) = tomllib.loads(text)["devices"]
    assert node["node_id"] == 2 and {o["index"] for o in node["objects"]} >= {i for i, _ in read}


def _candump(path, frames: list[tuple[float, int, str]]) -> None:
    """A candump log (python-can's ``.log`` writer's format) of ``(t, can_id, hex data)`` frames."""
    path.write_text("".join(f"({1_800_000_000 + t:.6f}) can0 {cob:03X}#{data.replace(' ', '')} R\n"
                            for t, cob, data in frames))


def test_a_reset_restarts_the_heartbeat_period(tmp_path):
    """A node the host resets: its heartbeat timer counts from the boot-up, so the interval from the heartbeat
    before the reset to the one after it is no period (its median with one real interval was 1180 ms)."""
    path = tmp_path / "reset.log"
    _candump(path, [(0.0, 0x702, "7f"), (0.33, 0x000, "81 02"), (0.36, 0x702, "00"),
                    (1.36, 0x702, "7f"), (2.36, 0x702, "7f")])
    draft, _, text = infer_file(path, baud=500_000)
    (node,) = tomllib.loads(text)["devices"]
    assert node["heartbeat_ms"] == 1000, text
    assert "heartbeat every 1000.0 ms" in "\n".join(draft.seen)


def test_verify_waits_for_nodes_the_capture_found_running(tmp_path):
    """A capture that starts with the host's SDO upload (the node booted long before): the replay's clock starts
    once the bench's node has booted, so the first upload is answered (it went unanswered while the node was in
    its 20 ms boot delay)."""
    path = tmp_path / "running.log"
    frames = [(0.0, 0x602, "40 18 10 01 00 00 00 00"), (0.0003, 0x582, "43 18 10 01 4e 42 48 00"),
              (0.002, 0x602, "40 00 10 00 00 00 00 00"), (0.0023, 0x582, "43 00 10 00 00 00 00 00")]
    frames += [(0.1 + k, 0x702, "7f") for k in range(3)]
    _candump(path, frames)
    draft, _, text = infer_file(path, baud=500_000)
    with Bench(check_profile_text(text)).start() as bench:
        report = draft.replay.run(bench, speed=1.0)
    assert (report.replies, report.matched_content) == (3, 2), report.lines()  # 2 uploads + the heartbeat stream
    assert report.matched == 3, report.lines()


def test_boot_up_nmt_states_and_emcy_are_told(tmp_path):
    """A node that boots, reports an EMCY, is started by the host and beats every 500 ms: the header names the
    boot-up, the NMT states its heartbeats carried and the EMCY (which the bench does not send)."""
    path = tmp_path / "emcy.log"
    frames = [(0.0, 0x702, "00"), (0.05, 0x082, "10 23 01 00 00 00 00 00"), (0.5, 0x702, "7f"),
              (0.7, 0x000, "01 02")]
    frames += [(1.0 + 0.5 * k, 0x702, "05") for k in range(4)]
    frames += [(0.71 + 0.1 * k, 0x182, "01 02") for k in range(25)]
    _candump(path, sorted(frames))
    draft, _, text = infer_file(path, baud=500_000)
    seen = "\n".join(draft.seen)
    assert "node 2: heartbeat every 500.0 ms, boot-up at 0.000 s; PDO 0x182 every 100.0 ms" in seen
    assert "EMCY 0x2310 (continuous over current), error register 0x01, at 0.050 s" in seen
    assert "# node 2: 1 boot-up(s), 5 heartbeats (OPERATIONAL 4x, PRE-OPERATIONAL 1x)" in text
    assert "#   EMCY seen (not sent by the bench): 0x2310 (continuous over current)" in text
    (node,) = tomllib.loads(text)["devices"]
    assert (node["heartbeat_ms"], node["autostart"]) == (500, False)  # the host's NMT start makes it OPERATIONAL
    assert "NMT start to node 2 at 0.700 s" in draft.pattern
    # a --baud no CAN bus runs at: reported, and the profile still loads (as a servo bus's impossible rate is)
    draft, _, text = infer_file(path, baud=12)
    assert draft.contradictions == ["the capture's 12 bit/s is no CAN bitrate (an emulated bus runs at "
                                    "10000..1000000): 500000 used"]
    assert tomllib.loads(text)["endpoints"]["can"]["bitrate"] == 500_000


def _converted(rover_log, tmp_path, suffix: str):
    """The rover recording in another python-can format (hilbench's CAN recorder, python-can's writers)."""
    from hilbench.transports.can_log import CanLogRecorder
    from hilbench.transports.sources import open_source

    path, _ = rover_log
    other = tmp_path / f"rover{suffix}"
    rec = CanLogRecorder(str(other))
    with open_source(str(path)) as source:
        for chunk in source:
            rec.chunk(chunk)
    rec.close()
    return other


@pytest.mark.parametrize(("suffix", "said"), [
    (".asc", "capture: truncated: the last line has no end (the recording was cut off)"),
    (".csv", "capture: truncated: the last line has no end (the recording was cut off)"),
    (".trc", "capture: truncated: the last line has no end (the recording was cut off)"),
    (".blf", "capture: truncated: the file is "),
])
def test_cut_and_empty_python_can_logs(rover_log, tmp_path, capsys, suffix, said):
    """A python-can log cut in the middle (a recorder killed, a copy that stopped) gives the node it shows and says
    the file is cut; an empty one is refused in one line (it gave an empty profile, or python-can's words about
    a struct for a BLF)."""
    full = _converted(rover_log, tmp_path, suffix)
    data = full.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    end = len(data) // 2 if suffix == ".blf" else data.index(b"\n", len(data) // 2) - 2  # (text: in a line)
    cut.write_bytes(data[:end])
    draft, _, text = infer_file(cut, baud=500_000)
    assert any(line.startswith(said) for line in draft.unread), draft.unread
    assert tomllib.loads(text)["devices"][0]["node_id"] == 2
    empty = tmp_path / f"empty{suffix}"
    empty.write_bytes(b"")
    assert main(["profiles", "from-capture", str(empty)]) == 2
    assert capsys.readouterr().err == f"hilbench: error: {empty}: the capture is empty\n"


def test_a_damaged_trc_line_is_counted_not_printed(rover_log, tmp_path, capsys):
    """python-can's TRC reader skips a line it cannot parse with a warning on stderr: it is counted in the header
    instead, and the frames after it are read."""
    full = _converted(rover_log, tmp_path, ".trc")
    lines = full.read_text().splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if not line.startswith(";")) + 5
    lines[k] = "   42) garbage\n"
    damaged = tmp_path / "damaged.trc"
    damaged.write_text("".join(lines))
    draft, _, text = infer_file(damaged, baud=500_000)
    assert any(line.startswith("capture: 1 record(s) python-can's reader could not parse, skipped (the first: "
                               "TRCReader: Failed to parse message") for line in draft.unread), draft.unread
    assert len(tomllib.loads(text)["devices"][0]["tpdos"]) == 4
    assert capsys.readouterr().err == ""
