"""The generic part of ``hilbench profiles from-capture``: the TOML it writes, the output rules, the verb."""

from __future__ import annotations

import json
import re
import tomllib

import pytest

from hilbench import registry
from hilbench.bench.capture_profile import (
    Commented,
    Hex,
    ProfileDraft,
    SourceFacts,
    Table,
    check_profile_text,
    id_ranges,
    inferrer_for,
    render,
)
from hilbench.cli import main
from hilbench.errors import UsageError
from hilbench.protocols import dynamixel as dxl


def _capture(tmp_path):
    """A raw dump: one XM430-W350 at ID 1 answering a Ping and a read of its position."""
    path = tmp_path / "bus.bin"
    path.write_bytes(dxl.instruction_packet(1, dxl.Instruction.PING) + dxl.status_packet(1, 0, bytes([0xFC, 3, 52]))
                     + dxl.instruction_packet(1, dxl.Instruction.READ, bytes([132, 0, 4, 0]))
                     + dxl.status_packet(1, 0, (2048).to_bytes(4, "little")))
    return path


def test_render_writes_toml_that_reads_back_with_its_comments():
    draft = ProfileDraft(description='a "quoted" bus')
    draft.seen.append("one device")
    draft.contradictions.append("ID 1 reads another ID")
    draft.endpoints["dxl"] = Table().set("type", "pty").set("protocol", "dynamixel").set("baud", 1_000_000, "rate")
    dev = Table(comment=["ID 1: seen"]).set("model", "XM430-W350").set("id", 1)
    dev.set("registers", [Commented({"address": Hex(0x24, 4), "size": 4}, "a note")], "the registers")
    draft.devices.append(dev)
    draft.devices.append(Table(comment=["ID 9: silent"], disabled=True).set("model", "XM430-W350").set("id", 9))
    text = render(draft, SourceFacts("cap.bin", "dynamixel", baud=1_000_000, baud_from="--baud"))
    data = tomllib.loads(text)
    assert data["description"] == 'a "quoted" bus'
    assert data["endpoints"]["dxl"]["baud"] == 1_000_000
    assert data["devices"] == [{"model": "XM430-W350", "id": 1, "registers": [{"address": 0x24, "size": 4}]}]
    assert data == draft.data()
    assert "  { address = 0x0024, size = 4 },   # a note" in text
    assert "# Contradictions in the capture (reported, not applied):\n#   ID 1 reads another ID" in text
    assert "# id    = 9" in text  # the silent device: a comment to enable by hand
    assert "# Seen:\n#   one device" in text


def test_id_ranges():
    assert id_ranges([1, 2, 3, 4, 5, 6, 19, 20]) == "1-6, 19, 20"
    assert id_ranges([7, 10, 12]) == "7, 10, 12"
    assert id_ranges([]) == ""


def test_inferrers_come_from_the_registry_and_a_protocol_without_one_is_refused():
    assert {"dynamixel", "feetech", "canopen"} <= set(registry.inferrers.names())
    assert "dynamixel1" in inferrer_for("dynamixel1").protocols
    with pytest.raises(UsageError, match=r"no profile inferrer reads vel2d traffic \(known: can, dynamixel, "):
        inferrer_for("vel2d")


def test_a_second_inferrer_for_a_protocol_is_refused():
    """Inferrers claim their protocols: one that reads a protocol another one reads is refused, naming it."""

    class Other:
        title = "another Dynamixel reader"
        protocols = ("dynamixel",)

    with pytest.raises(ValueError, match=r"its protocol 'dynamixel' is taken by profile inferrer 'dynamixel'"):
        registry.inferrers.register("other-dxl", Other())
    assert "other-dxl" not in registry.inferrers


def test_plugins_lists_the_inferrers_with_their_protocols(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    assert "Dynamixel servo buses (Protocol 2.0 and 1.0): profiles from dynamixel, dynamixel1 captures" in out
    assert "CANopen nodes on a CAN bus: profiles from can captures" in out


def test_from_capture_writes_a_profile_that_emulate_loads(tmp_path, capsys, hilbench_emulator):
    out = tmp_path / "robot.toml"
    assert main(["profiles", "from-capture", str(_capture(tmp_path)), "--baud", "1000000", "-o", str(out)]) == 0
    assert "wrote" in capsys.readouterr().err
    text = out.read_text()
    assert text.startswith("# A bench of the bus recorded in")
    assert "with `hilbench profiles from-capture bus.bin -o robot.toml --baud 1000000`." in text
    profile = check_profile_text(text)
    assert [(s.id, s.model) for s in profile.devices] == [(1, "XM430-W350")]
    # the unchanged file starts a bench: `hilbench emulate` reads it as any profile
    manifest = hilbench_emulator(str(out))
    assert [(d["id"], d["model"]) for d in manifest["devices"]] == [(1, "XM430-W350")]


def test_from_capture_keeps_what_the_user_has(tmp_path, capsys):
    cap = _capture(tmp_path)
    out = tmp_path / "robot.toml"
    out.write_text("# my edited profile\n")
    assert main(["profiles", "from-capture", str(cap), "-o", str(out)]) == 2
    assert "-o " + str(out) + " exists: --force replaces it" in capsys.readouterr().err
    assert out.read_text() == "# my edited profile\n"
    assert main(["profiles", "from-capture", str(cap), "-o", str(out), "--force"]) == 0
    assert out.read_text().startswith("# A bench")
    assert main(["profiles", "from-capture", str(cap), "-o", str(cap)]) == 2  # onto its own input
    assert "is the input" in capsys.readouterr().err
    assert cap.read_bytes().startswith(b"\xff\xff\xfd")
    assert main(["profiles", "from-capture", str(cap), "-o", str(tmp_path / "no" / "dir.toml")]) == 2
    assert main(["profiles", "from-capture", str(tmp_path / "gone.bin")]) == 1
    assert "gone.bin: no such file" in capsys.readouterr().err


def test_from_capture_refuses_what_it_cannot_read(tmp_path, capsys):
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert main(["profiles", "from-capture", str(empty)]) == 2
    assert "the capture is empty" in capsys.readouterr().err
    noise = tmp_path / "noise.bin"
    noise.write_bytes(bytes(range(256)) * 4)
    assert main(["profiles", "from-capture", str(noise)]) == 2
    assert "no known traffic recognised" in capsys.readouterr().err
    assert main(["profiles", "from-capture", str(_capture(tmp_path)), "--protocol", "feetech"]) == 0  # told
    assert main(["profiles", "from-capture", "bench:arm"]) == 2
    assert "record a bench first" in capsys.readouterr().err


def test_from_capture_prints_to_stdout_and_json(tmp_path, capsys):
    cap = _capture(tmp_path)
    assert main(["profiles", "from-capture", str(cap), "--baud", "1000000"]) == 0
    assert tomllib.loads(capsys.readouterr().out)["devices"][0]["model"] == "XM430-W350"
    assert main(["profiles", "from-capture", str(cap), "--baud", "1000000", "--json", "--verify", "--speed",
                 "0"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["protocol"] == "dynamixel" and doc["profile"] is None
    assert tomllib.loads(doc["text"])["endpoints"]["dxl"]["baud"] == 1_000_000
    assert doc["verify"]["replies"] == 2 and doc["verify"]["ratio"] == 1.0


def test_verify_fails_below_the_minimum_ratio(tmp_path, capsys):
    """A capture whose servo answers what no bench of its profile can: its reply to a Write carries an error."""
    path = tmp_path / "err.bin"
    path.write_bytes(dxl.instruction_packet(1, dxl.Instruction.PING) + dxl.status_packet(1, 0, bytes([0xFC, 3, 52]))
                     + dxl.instruction_packet(1, dxl.Instruction.WRITE, bytes([65, 0, 1]))
                     + dxl.status_packet(1, dxl.ErrorNumber.DATA_RANGE_ERROR))
    code = main(["profiles", "from-capture", str(path), "--baud", "1000000", "-o", str(tmp_path / "p.toml"),
                 "--verify", "--speed", "0", "--min-ratio", "0.9"])
    out, err = capsys.readouterr()
    assert code == 3
    assert "verify dxl: 1 of 2 captured replies match (50.0 %)" in out
    assert "write of ID 1 at 0.000480 s: ID 1 sent ff ff fd 00 01 04 00 55 00 a1 0c, the capture ff ff fd 00 01 04 " \
           "00 55 04 ba 8c" in out
    assert "50.0 % of the replies match, less than 90 %" in err


def test_verify_does_not_crawl_where_the_bench_does_not_answer(tmp_path):
    """The replay waits long for a reply while the bench answers (a late one on a loaded machine is no missing
    reply) but briefly once it has left one unanswered: a bench whose servo is gone is done in seconds, not in
    a second per request."""
    from hilbench.bench import Bench
    from hilbench.bench.capture_profile import InferOptions, infer, traffic_of
    from hilbench.transports.sources import open_source

    path = tmp_path / "bus.bin"
    packets = dxl.instruction_packet(1, dxl.Instruction.PING) + dxl.status_packet(1, 0, bytes([0xFC, 3, 52]))
    for k in range(20):
        packets += dxl.instruction_packet(1, dxl.Instruction.READ, bytes([132, 0, 4, 0]))
        packets += dxl.status_packet(1, 0, (2048 + k).to_bytes(4, "little"))
    path.write_bytes(packets)
    with open_source(str(path), baud=1_000_000) as source:
        traffic, source = traffic_of(source, None)
        draft, facts = infer(source, traffic, baud=1_000_000, baud_from="--baud", options=InferOptions())
    text = re.sub(r"(?m)^(id +=) 1$", r"\1 1\nfaults = { vanished = true }", render(draft, facts), count=1)
    assert "vanished" in text
    with Bench(check_profile_text(text)).start() as bench:
        report = draft.replay.run(bench, speed=None)
    assert (report.replies, report.missing) == (21, 21), report.lines()
    assert report.seconds < 1.0 + 20 * 0.05 + 2.0, report.lines()  # one patient wait, then 50 ms each
