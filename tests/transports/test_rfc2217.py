"""A bench served over RFC 2217: pyserial's rfc2217:// client and the official SDK talk to the emulated bus.

Real parts only: the bench's devices on a real serial medium, the server on 127.0.0.1, pyserial's own
RFC 2217 client (or pyserial-labgrid's, when that is the installed ``serial``), the unmodified
dynamixel-sdk through :class:`~hilbench.clients.dynamixel.UrlPortHandler`, raw sockets for what no
client exposes.
"""

from __future__ import annotations

import contextlib
import json
import re
import socket
import subprocess
import sys
import time

import dynamixel_sdk as sdk
import pytest
import serial

from hilbench.clients.dynamixel import UrlPortHandler
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import rfc2217 as p
from hilbench.pytest_plugin import wait_until
from hilbench.transports.port_state import BreakCondition, ModemSignals, SerialSettings
from hilbench.transports.rfc2217 import MAX_BACKLOG, MAX_HELD, RECV_SIZE

OK = sdk.COMM_SUCCESS
PING_1 = dxl.instruction_packet(1, dxl.Instruction.PING)


class PortEventRecorder:
    """An in-process party on the line that records the line events it hears (as an RPLIDAR's motor would)."""

    name = "recorder"

    def __init__(self) -> None:
        self.events: list = []

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        pass

    def on_port_event(self, event, t: float) -> None:
        self.events.append(event)


@pytest.fixture
def served(hilbench_bench):
    """The arm bench (XM430s at 1 Mbaud) with its endpoint served over RFC 2217, and a line recorder."""
    bench = hilbench_bench("arm", serve=["rfc2217"])
    ep = bench.endpoint()
    recorder = PortEventRecorder()
    ep.medium.add_device(recorder)
    return bench, ep, ep.services["rfc2217"].url, recorder


def _ping(port: serial.SerialBase, dxl_id: int = 1) -> dxl.StatusPacket | None:
    port.reset_input_buffer()
    port.write(dxl.instruction_packet(dxl_id, dxl.Instruction.PING))
    raw = port.read(14)
    items = dxl.Decoder().feed(raw)
    return items[0] if items and isinstance(items[0], dxl.StatusPacket) else None


def test_the_manifest_lists_the_rfc2217_url_and_the_bench_name(served):
    bench, ep, url, _ = served
    manifest = bench.manifest()
    assert manifest["name"] == "arm"
    entry = manifest["endpoints"][0]
    assert entry["rfc2217"] == url
    assert url.startswith("rfc2217://127.0.0.1:")
    assert entry["path"] == ep.port.client_path  # the pty stays where it was


def test_pyserial_pings_and_reads_a_servo(served):
    bench, _, url, _ = served
    with serial.serial_for_url(url, baudrate=1_000_000, timeout=1) as port:
        reply = _ping(port, 1)
        assert reply is not None and reply.id == 1 and reply.error == 0
        assert int.from_bytes(reply.data[:2], "little") == 1020  # XM430-W350
        bench.device(3).set("profile_velocity", 1234)  # read back over the wire (address 112)
        port.write(dxl.instruction_packet(3, dxl.Instruction.READ, (112).to_bytes(2, "little") + b"\x04\x00"))
        items = dxl.Decoder().feed(port.read(15))
        assert items and items[0].id == 3 and int.from_bytes(items[0].data, "little") == 1234


def test_the_official_sdk_syncs_over_rfc2217(served):
    bench, _, url, _ = served
    port, ph = UrlPortHandler(url), sdk.PacketHandler(2.0)
    assert port.openPort() and port.setBaudRate(1_000_000)
    try:
        assert ph.ping(port, 5) == (1060, OK, 0)  # the XL430-W250 gripper
        writer = sdk.GroupSyncWrite(port, ph, 112, 4)  # Profile Velocity
        for i in (1, 2, 3, 4):
            writer.addParam(i, list((i * 11).to_bytes(4, "little")))
        assert writer.txPacket() == OK
        reader = sdk.GroupSyncRead(port, ph, 112, 4)
        for i in (1, 2, 3, 4):
            reader.addParam(i)
        assert reader.txRxPacket() == OK
        assert [reader.getData(i, 112, 4) for i in (1, 2, 3, 4)] == [11, 22, 33, 44]
    finally:
        port.closePort()


def test_the_url_port_takes_every_byte_already_received_in_one_read(served):
    """pyserial's RFC 2217 client queues one item per received byte; the SDK's reads through UrlPortHandler
    take what is queued at once (up to the length asked for), and stop at the client's end-of-connection
    marker instead of swallowing it."""
    _, _, url, _ = served
    port = UrlPortHandler(url)
    assert port.openPort() and port.setBaudRate(1_000_000)
    try:
        queued = port.ser._read_buffer
        gets = []
        get = queued.get
        queued.get = lambda *a, **k: gets.append(1) or get(*a, **k)  # count pyserial's per-item gets
        for byte in b"abcdef":
            queued.put(bytes([byte]))
        assert port.readPort(4) == b"abcd"  # no more than asked for
        assert len(gets) == 1  # one get (the wait for the first byte), not one per byte
        assert port.readPort(10) == b"ef"  # what is there, without waiting for the rest
        assert port.readPort(3) == b""  # nothing: after the short wait
        queued.put(b"x")
        queued.put(None)
        assert port.readPort(5) == b"x" and list(queued.queue) == [None]  # the marker stays for pyserial
    finally:
        port.closePort()


def test_a_baud_change_reaches_the_line(served):
    """Servos hear only their own rate: the client's SET-BAUDRATE decides who answers, as on a real bus."""
    bench, ep, url, recorder = served
    with serial.serial_for_url(url, baudrate=57_600, timeout=0.3) as port:
        assert _ping(port) is None  # the bus runs at 1 Mbaud
        port.baudrate = 1_000_000
        assert _ping(port).id == 1
        assert ep.services["rfc2217"].client_baud() == 1_000_000
        # move servo 1 to 2 Mbaud (Baud Rate code 4), then follow it
        port.write(dxl.instruction_packet(1, dxl.Instruction.WRITE, (8).to_bytes(2, "little") + b"\x04"))
        assert dxl.Decoder().feed(port.read(11))[0].error == 0
        assert _ping(port, 1) is None
        port.baudrate = 2_000_000
        assert _ping(port, 1).id == 1
        assert _ping(port, 2) is None  # still at 1 Mbaud
    settings = [e for e in recorder.events if isinstance(e, SerialSettings)]
    assert [s.baud for s in settings] == [57_600, 1_000_000, 2_000_000]


def test_framing_changes_reach_the_line(served):
    _, ep, url, recorder = served
    with serial.serial_for_url(url, baudrate=1_000_000, timeout=1) as port:
        port.bytesize = serial.SEVENBITS
        port.parity = serial.PARITY_EVEN
        port.stopbits = serial.STOPBITS_TWO
    wait_until(lambda: any(isinstance(e, SerialSettings) and e.stopbits == 2.0 for e in recorder.events))
    last = [e for e in recorder.events if isinstance(e, SerialSettings)][-1]
    assert (last.baud, last.bytesize, last.parity, last.stopbits) == (1_000_000, 7, "E", 2.0)
    assert ep.port.port_state.settings == last


def test_dtr_rts_and_break_reach_the_devices_in_order(served):
    _, ep, url, recorder = served
    lines = ep.port.port_state
    with serial.serial_for_url(url, baudrate=1_000_000, timeout=1) as port:
        port.dtr = False
        port.rts = False
        port.break_condition = True
        port.break_condition = False
        port.dtr = True
        wait_until(lambda: lines.dtr)
        assert not lines.rts
    wait_until(lambda: not lines.dtr)  # closing the port drops DTR (HUPCL), as a real adapter's close does
    modem = [e for e in recorder.events if isinstance(e, ModemSignals | BreakCondition)]
    assert modem == [ModemSignals(False, True), ModemSignals(False, False), BreakCondition(True), BreakCondition(False),
                     ModemSignals(True, False), ModemSignals(False, False)]


def test_device_driven_modem_lines_reach_the_client(served):
    _, ep, url, _ = served
    with serial.serial_for_url(url, baudrate=1_000_000, timeout=1) as port:
        assert (port.cts, port.dsr, port.ri, port.cd) == (False, False, False, False)
        ep.port.port_state.device_sets(cts=True, dsr=True)
        wait_until(lambda: port.cts and port.dsr)
        ep.port.port_state.device_sets(dsr=False, ri=True, cd=True)
        wait_until(lambda: not port.dsr and port.ri and port.cd)
    # a polling client (poll_modem) asks for the state and gets it
    with serial.serial_for_url(url + "?poll_modem", baudrate=1_000_000, timeout=1) as port:
        assert (port.cts, port.dsr, port.ri, port.cd) == (True, False, True, True)


def test_labgrids_url_options_work(served):
    """labgrid's SerialDriver opens ``rfc2217://HOST:PORT?ign_set_control&timeout=3.0``."""
    _, _, url, _ = served
    with serial.serial_for_url(url + "?ign_set_control&timeout=3.0", baudrate=1_000_000, timeout=1) as port:
        assert _ping(port).id == 1


def test_reopen_loop(served):
    _, ep, url, _ = served
    service = ep.services["rfc2217"]
    for i in range(4):
        port = serial.serial_for_url(url, baudrate=1_000_000, timeout=1)
        try:
            assert _ping(port, 1 + i).id == 1 + i
        finally:
            port.close()
    wait_until(lambda: service.client is None)
    assert service.connections == 4 and service.refused == 0


def test_a_second_client_is_refused_with_a_reason_and_the_first_keeps_working(served):
    _, ep, url, _ = served
    host, port_number = url[len("rfc2217://"):].rsplit(":", 1)
    with serial.serial_for_url(url, baudrate=1_000_000, timeout=1) as first:
        with socket.create_connection((host, int(port_number)), timeout=2) as raw:
            text = b""
            while chunk := raw.recv(4096):
                text += chunk
        assert b"port busy" in text and b"in use by 127.0.0.1:" in text
        with pytest.raises((serial.SerialException, OSError)):  # pyserial sees the hang-up (EPIPE / reset)
            serial.serial_for_url(url + "?timeout=0.5", baudrate=1_000_000, timeout=1)  # (not its 3 s negotiation)
        assert _ping(first).id == 1
    assert ep.services["rfc2217"].refused == 2


def test_a_busy_port_is_reported_in_the_servers_words(served, capsys):
    """Not pyserial's "Broken pipe": the server's line, through every hilbench client that opens URLs."""
    from hilbench.cli import main
    from hilbench.transports.serial_url import open_url
    from hilbench.transports.sources import SourceError
    from hilbench.transports.sources.serial import SerialSource

    _, ep, url, _ = served
    # (pyserial's Telnet negotiation timeout: 3 s before each refusal is read, 0.5 s here)
    client_url = url + "?timeout=0.5"
    with serial.serial_for_url(client_url, baudrate=1_000_000, timeout=1) as first:
        holder = f"127.0.0.1:{first._socket.getsockname()[1]}"
        said = f"hilbench: port busy: arm:rfc2217 ({url}) is in use by {holder} since "
        refusal = "^the server refused: " + re.escape(said) + r"\d\d:\d\d:\d\d; one client at a time$"
        with pytest.raises(serial.SerialException, match=refusal):
            open_url(client_url, baudrate=1_000_000, timeout=1)
        with pytest.raises(SourceError, match="the server refused: hilbench: port busy"):
            SerialSource(client_url, 1_000_000)
        assert main(["dxl", "ping", client_url, "1", "--baud", "1000000"]) == 1
        (line,) = capsys.readouterr().err.splitlines()
        assert line.startswith(f"hilbench: error: cannot open {client_url}: the server refused: {said}")
        assert _ping(first).id == 1  # the holder keeps the port
    assert ep.services["rfc2217"].refused == 3


def test_the_tap_sees_the_remote_clients_traffic(served):
    _, ep, url, _ = served
    seen = []
    ep.medium.add_tap(lambda t, source, data: seen.append((source, data)))
    with serial.serial_for_url(url, baudrate=1_000_000, timeout=1) as port:
        assert _ping(port).id == 1
    wait_until(lambda: ("arm:rfc2217", PING_1) in seen)


# ---------------------------------------------------------------------- raw telnet: what clients do not show


class RawClient:
    """A minimal telnet client on a socket, for commands pyserial does not send."""

    def __init__(self, url: str) -> None:
        host, port = url[len("rfc2217://"):].rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=2)
        self.decoder = p.TelnetDecoder()
        self.items: list = []
        self.sock.sendall(p.negotiation(p.WILL, p.COM_PORT_OPTION) + p.negotiation(p.WILL, p.BINARY))

    def command(self, command: int, value: bytes = b"") -> None:
        self.sock.sendall(p.subnegotiation(command, value))

    def answer(self, command: int) -> bytes:
        def found():
            for item in self.items:
                if isinstance(item, p.Subnegotiation) and item.body[:1] == bytes([command + p.SERVER_OFFSET]):
                    self.items.remove(item)
                    return item.body[1:] or b"\x00"
            self.items.extend(self.decoder.feed(self.sock.recv(4096)))
            return None

        return wait_until(found)

    def data(self, n: int) -> bytes:
        def enough():
            got = b"".join(i.data for i in self.items if isinstance(i, p.Data))
            if len(got) >= n:
                return got
            self.items.extend(self.decoder.feed(self.sock.recv(4096)))
            return None

        return wait_until(enough)

    def close(self) -> None:
        self.sock.close()


def test_raw_commands_are_answered(served):
    bench, ep, url, _ = served
    c = RawClient(url)
    try:
        c.command(p.Command.SIGNATURE)
        assert b"bench arm endpoint arm" in c.answer(p.Command.SIGNATURE)
        c.command(p.Command.SET_BAUDRATE, b"\x00\x00\x00\x00")  # 0 asks for the current rate
        assert c.answer(p.Command.SET_BAUDRATE) == (1_000_000).to_bytes(4, "big")
        c.command(p.Command.SET_DATASIZE, b"\x09")  # not a data size: the answer keeps the current one
        assert c.answer(p.Command.SET_DATASIZE) == b"\x08"
        for ask, expected in ((p.Control.REQ_DTR, p.Control.DTR_ON), (p.Control.REQ_RTS, p.Control.RTS_ON),
                              (p.Control.REQ_BREAK, p.Control.BREAK_OFF), (p.Control.REQ_FLOW, p.Control.FLOW_NONE)):
            c.command(p.Command.SET_CONTROL, bytes([ask]))
            assert c.answer(p.Command.SET_CONTROL) == bytes([expected])
        c.command(p.Command.SET_CONTROL, bytes([p.Control.FLOW_HARDWARE]))
        assert c.answer(p.Command.SET_CONTROL) == bytes([p.Control.FLOW_HARDWARE])
        c.command(p.Command.SET_MODEMSTATE_MASK, b"\x30")
        assert c.answer(p.Command.SET_MODEMSTATE_MASK) == b"\x30"
        ep.port.port_state.device_sets(cd=True, dsr=True)  # CD is masked out now
        assert c.answer(p.Command.NOTIFY_MODEMSTATE)[0] & 0xF0 in (0x00, 0x20)
        assert ep.services["rfc2217"].status()["flow"] == "hardware"
    finally:
        c.close()


def test_flow_suspend_holds_the_devices_bytes_until_resume(served):
    _, ep, url, _ = served
    c = RawClient(url)
    try:
        c.command(p.Command.SET_BAUDRATE, (1_000_000).to_bytes(4, "big"))
        c.answer(p.Command.SET_BAUDRATE)
        c.command(p.Command.FLOWCONTROL_SUSPEND)
        c.sock.sendall(p.escape(PING_1))
        service = ep.services["rfc2217"]
        wait_until(lambda: len(service._held) == 14)
        c.command(p.Command.FLOWCONTROL_RESUME)
        reply = dxl.Decoder().feed(c.data(14))
        assert reply[0].id == 1
    finally:
        c.close()


# ---------------------------------------------------------------------- hostile clients: bounds


def test_an_ayt_flood_from_a_client_that_reads_nothing_is_bounded_and_counted(served):
    # 32 MiB of IAC AYT from a client that read nothing grew the bench by 276 MB: every AYT queued an answer.
    _, ep, url, _ = served
    service = ep.services["rfc2217"]
    host, port = url[len("rfc2217://"):].rsplit(":", 1)
    client = socket.socket()
    client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    client.connect((host, int(port)))
    try:
        client.sendall(bytes([p.IAC, p.AYT]) * (256 << 10))  # 256 Ki of them: more than the kernel holds
        wait_until(lambda: service.bytes_in == 0 and service.replies_dropped > 100_000, timeout=30)
        status = service.status()
        assert status["held_bytes"] <= MAX_HELD  # what waits for the client stays bounded
        client.setblocking(False)
        answers = b""
        with contextlib.suppress(BlockingIOError):
            while chunk := client.recv(1 << 16):
                answers += chunk
        assert b"[hilbench: yes]" in answers  # answered, the rest coalesced
    finally:
        client.close()
    wait_until(lambda: service.client is None)
    with serial.serial_for_url(url, baudrate=1_000_000, timeout=1) as again:  # the next client is served
        assert _ping(again).id == 1


def test_a_baud_rate_no_port_has_is_not_applied(served):
    _, ep, url, recorder = served
    c = RawClient(url)
    try:
        for rate in (0xFFFF_FFFF, 20_000_001, 49):
            c.command(p.Command.SET_BAUDRATE, rate.to_bytes(4, "big"))
            assert c.answer(p.Command.SET_BAUDRATE) == (1_000_000).to_bytes(4, "big")  # the rate kept
        assert ep.services["rfc2217"].status()["problems"] == 3
        c.command(p.Command.SET_BAUDRATE, (50).to_bytes(4, "big"))  # the lowest termios rate is taken
        assert c.answer(p.Command.SET_BAUDRATE) == (50).to_bytes(4, "big")
    finally:
        c.close()


def test_a_paced_line_reads_the_client_only_as_fast_as_the_wire_takes_its_bytes(hilbench_bench):
    # A client writing faster than the baud rate was read at once and its bytes queued at wire pace without
    # bound; now TCP holds it back, as a UART's full FIFO holds a writer.
    bench = hilbench_bench("arm", serve=["rfc2217"], paced=True)
    ep = bench.endpoint()
    service = ep.services["rfc2217"]
    c = RawClient(service.url)
    try:
        c.command(p.Command.SET_BAUDRATE, (1_000_000).to_bytes(4, "big"))
        c.answer(p.Command.SET_BAUDRATE)
        c.sock.setblocking(False)
        block, pushed = bytes(4096), 0
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:  # ~8 MB offered within a second: 80 s of wire time at 1 Mbaud
            with contextlib.suppress(BlockingIOError):
                pushed += c.sock.send(block)
            assert ep.medium.backlog(service.name) <= MAX_BACKLOG + RECV_SIZE * 10 / 1_000_000 + 0.05
        assert service.bytes_in < pushed  # the rest waits in TCP, not in the bench
    finally:
        c.close()


# ---------------------------------------------------------------------- the command line


def test_emulate_serves_rfc2217_and_hilbench_dxl_reaches_it(hilbench_emulator):
    manifest = hilbench_emulator("arm", "--serve", "rfc2217")
    assert manifest["name"] == "arm"
    url = manifest["endpoints"][0]["rfc2217"]
    assert url.startswith("rfc2217://127.0.0.1:")
    out = subprocess.run([sys.executable, "-m", "hilbench.cli", "dxl", "ping", url, "4", "--baud", "1000000",
                          "--json"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["model"] == 1020


def test_emulate_rejects_an_unknown_server_and_an_endpoint_it_cannot_serve(tmp_path):
    run = [sys.executable, "-m", "hilbench.cli", "emulate"]
    out = subprocess.run([*run, "arm", "--serve", "carrier-pigeon"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "unknown server 'carrier-pigeon' (known: rfc2217" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    out = subprocess.run([*run, "mecarover-udp", "--serve", "rfc2217"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "has no endpoint rfc2217 can serve" in out.stderr


def test_bind_beyond_loopback_warns(hilbench_emulator):
    # 0.0.0.0 is asked for explicitly here; the test only ever connects through 127.0.0.1
    manifest = hilbench_emulator("arm", "--serve", "rfc2217", "--bind", "0.0.0.0")
    entry = manifest["endpoints"][0]
    assert entry["rfc2217"].startswith("rfc2217://127.0.0.1:") and entry["rfc2217_bind"] == "0.0.0.0"
    proc = manifest["process"]
    proc.terminate()
    _, err = proc.communicate(timeout=10)
    assert "warning: --bind 0.0.0.0" in err and "SSH" in err
