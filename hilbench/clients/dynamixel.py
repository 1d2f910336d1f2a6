"""Talking to any Dynamixel port, real or emulated, through the official ``dynamixel-sdk``.

These helpers back ``hilbench dxl``. They use the unmodified SDK on purpose:
what works here works in a user's own SDK program, on a U2D2 or on a bench.
SDK result codes become :class:`DxlError` with the SDK's own wording.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import dynamixel_sdk as sdk
import serial
from serial import rfc2217

from hilbench.errors import DeviceError, UsageError
from hilbench.protocols.dynamixel import describe_error
from hilbench.protocols.dynamixel_models import MODEL_NAMES, MODELS_BY_NUMBER, Field, Model
from hilbench.protocols.dynamixel_protocol1 import ERROR_BITS as P1_ERROR_BITS
from hilbench.transports.serial_url import check_port, open_url

#: Baud rates tried by ``scan`` by default: the Dynamixel baud codes the SDK can open.
SCAN_BAUDS = (57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 9_600)


class DxlError(DeviceError, RuntimeError):
    """A failed exchange; the message says what and why in one line (exit status 1 on the command line)."""


class DxlRequestError(UsageError, ValueError):
    """A request that cannot be made (an item the model does not have, a value too big): exit status 2."""


@dataclass(frozen=True)
class Found:
    """A device that answered a ping."""

    id: int
    model_number: int
    firmware: int
    baud: int

    @property
    def model_name(self) -> str:
        return MODEL_NAMES.get(self.model_number, f"unknown ({self.model_number})")


#: How long a URL port's read waits for bytes (s); see :class:`UrlPortHandler`.
URL_READ_WAIT = 0.002


class UrlPortHandler(sdk.PortHandler):
    """The official SDK's PortHandler that also opens pyserial URLs (``rfc2217://HOST:PORT``, ``socket://``).

    The SDK opens ports with ``serial.Serial(path)``, which takes device paths only; this subclass
    changes that one step (``serial.serial_for_url``) and keeps everything else, so the SDK's
    packet handler and group reads/writes run unchanged over a remote bench. A baud change on an
    open URL port changes the rate on the same connection instead of reopening it.

    Reads wait up to :data:`URL_READ_WAIT` for bytes instead of returning at once: the SDK polls in a
    loop that never sleeps, and a URL port's bytes arrive through a reader thread (pyserial's
    rfc2217 client) that needs the interpreter lock the polling loop holds; a short blocking wait
    hands it over (without it a 20-servo cycle runs at a fifth of the rate).
    ``clearPort`` (the SDK calls it before every packet) drops the bytes that have arrived instead of
    asking the server to purge: over RFC 2217 a purge is a round trip whose acknowledgement
    pyserial's client polls for in 50 ms steps, which would cap the SDK at a few packets per second.
    """

    def readPort(self, length: int) -> bytes:  # noqa: N802 (the SDK's name)
        """Up to ``length`` bytes: waits up to :data:`URL_READ_WAIT` for the first, then takes every byte
        already received.

        pyserial's RFC 2217 client queues each received byte as an item of its own and its ``read`` takes
        them one by one (a liveness check, a timeout computation and a queue get per byte: most of a
        remote 20-servo cycle's time); the bytes already queued are taken here in one step under the
        queue's lock. Other URL ports (``socket://``, ``loop://``) read as the SDK does.
        """
        ser = self.ser
        queued = getattr(ser, "_read_buffer", None) if isinstance(ser, rfc2217.Serial) else None
        if queued is None or length <= 1:
            return ser.read(length)
        data = ser.read(1)
        if data:
            with queued.mutex:  # (queue.Queue's own lock: what get() takes, once instead of per byte)
                items, more = queued.queue, bytearray(data)
                while items and len(more) < length and items[0] is not None:  # None: the client closed
                    more += items.popleft()
                queued.not_full.notify_all()
            data = bytes(more)
        return data

    def clearPort(self) -> None:  # noqa: N802 (the SDK's name)
        waiting = self.ser.in_waiting
        if waiting:
            self.ser.read(waiting)

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 (the SDK's name)
        if self.is_open and self.ser is not None:
            self.ser.baudrate = self.baudrate
        else:
            self.ser = open_url(self.port_name, baudrate=self.baudrate, bytesize=serial.EIGHTBITS,
                                timeout=URL_READ_WAIT)
            self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True


def port_handler(path: str) -> sdk.PortHandler:
    """The SDK's PortHandler for a device path, :class:`UrlPortHandler` for a URL (``rfc2217://...``)."""
    return UrlPortHandler(path) if "://" in path else sdk.PortHandler(path)


@contextlib.contextmanager
def open_port(path: str, baud: int) -> Iterator[sdk.PortHandler]:
    """Open ``path`` (a device or an ``rfc2217://`` URL) at ``baud`` with the SDK, closing it afterwards."""
    check_port(path)
    port = port_handler(path)
    try:
        opened = port.openPort()
    except Exception as exc:  # pyserial raises SerialException with the OS reason
        raise DxlError(f"cannot open {path}: {exc}") from None
    if not opened:
        raise DxlError(f"cannot open {path}")
    try:
        if not port.setBaudRate(baud):
            raise DxlError(f"the Dynamixel SDK cannot use {baud} baud")
        yield port
    finally:
        with contextlib.suppress(Exception):
            port.closePort()


#: Protocol 1.0 status bits that say the instruction was refused or changed (angle limit: the goal was clamped);
#: the others (input voltage, overheating, overload) describe the servo's condition, as Protocol 2.0's Alert bit.
P1_REFUSALS = 0x02 | 0x08 | 0x10 | 0x40


def packet_handler(protocol: float = 2.0):
    return sdk.PacketHandler(protocol)


def _once_more(call: Callable[[], tuple]) -> tuple:
    """``call()`` (an SDK request: its result code second to last), sent once more if no reply came within the
    SDK's timeout: a loaded host or a noisy bus loses one now and then, and every request made here (ping,
    read, write of a register) may be repeated; a device that is not there costs two timeouts."""
    out = call()
    if out[-2] == sdk.COMM_RX_TIMEOUT:
        out = call()
    return out


def _check(ph, result: int, error: int, what: str) -> None:
    if result != sdk.COMM_SUCCESS:
        raise DxlError(f"{what}: {ph.getTxRxResult(result)}")
    if ph.getProtocolVersion() == 1.0:
        if error & P1_REFUSALS:
            bits = ", ".join(name for bit, name in P1_ERROR_BITS.items() if error & P1_REFUSALS & bit)
            raise DxlError(f"{what}: device reports {bits} error")
    elif error & 0x7F:
        raise DxlError(f"{what}: device reports {describe_error(error)}")


def ping(path: str, dxl_id: int, baud: int, protocol: float = 2.0) -> Found:
    """Ping one ID; returns model and firmware."""
    ph = packet_handler(protocol)
    with open_port(path, baud) as port:
        model, result, error = _once_more(lambda: ph.ping(port, dxl_id))
        _check(ph, result, error, f"ping ID {dxl_id} at {baud} baud")
        known = MODELS_BY_NUMBER.get(model)
        if protocol == 2.0:
            fw_address = 2 if model in (0xABBA, 0xAFFE, 0xBAFF) else 6
        else:  # Protocol 1.0 has no firmware in its Ping reply: read it where the model keeps it
            fw_address = known.firmware_address if known is not None else 2
        firmware, result, error = _once_more(lambda: ph.read1ByteTxRx(port, dxl_id, fw_address))
        _check(ph, result, error, f"read firmware of ID {dxl_id}")
        return Found(dxl_id, model, firmware, baud)


#: ``scan``'s progress callback: (baud, the ID being pinged or None for a broadcast, devices found so far).
ScanProgress = Callable[[int, int | None, int], None]


def scan(path: str, bauds: tuple[int, ...] = SCAN_BAUDS, protocol: float = 2.0,
         progress: ScanProgress | None = None) -> list[Found]:
    """Find devices at each baud rate with a broadcast ping (Protocol 2.0) or ID-by-ID pings (1.0, which
    has no broadcast ping: 253 pings per rate, about 9 s each with the SDK's timeout); ``progress`` is
    called before each ping."""
    ph = packet_handler(protocol)
    found: list[Found] = []
    for baud in bauds:
        with open_port(path, baud) as port:
            if protocol == 2.0:
                if progress:
                    progress(baud, None, len(found))
                replies, result = ph.broadcastPing(port)
                if result not in (sdk.COMM_SUCCESS, sdk.COMM_RX_TIMEOUT, sdk.COMM_RX_CORRUPT):
                    raise DxlError(f"broadcast ping at {baud}: {ph.getTxRxResult(result)}")
                for dxl_id, (model, firmware) in sorted(replies.items()):
                    found.append(Found(dxl_id, model, firmware, baud))
            else:
                for dxl_id in range(0, 253):
                    if progress:
                        progress(baud, dxl_id, len(found))
                    model, result, _ = ph.ping(port, dxl_id)
                    if result == sdk.COMM_SUCCESS:
                        known = MODELS_BY_NUMBER.get(model)
                        fw, result, _ = ph.read1ByteTxRx(port, dxl_id, known.firmware_address if known else 2)
                        found.append(Found(dxl_id, model, fw if result == sdk.COMM_SUCCESS else 0, baud))
    return found


def resolve_field(model: Model | None, item: str, length: int | None) -> tuple[int, int, Field | None]:
    """(address, size, field) from an address number or a control-table item name."""
    if item.isdigit():
        address = int(item)
        f = model.field_at(address) if model else None
        size = length or (f.size if f else None)
        if size is None:
            raise DxlRequestError(f"address {address}: give a length (unknown item)")
        return address, size, f
    if model is None:
        raise DxlRequestError(f"{item!r}: unknown model, give an address and length instead of a name")
    try:
        f = model.field_named(item)
    except KeyError as exc:
        raise DxlRequestError(str(exc.args[0])) from None
    return f.address, length or f.size, f


def read(path: str, dxl_id: int, item: str, baud: int, length: int | None = None,
         protocol: float = 2.0) -> tuple[int, bytes, Field | None]:
    """Read an item (by name or address) with the SDK; returns (address, raw bytes, field)."""
    ph = packet_handler(protocol)
    with open_port(path, baud) as port:
        number, result, error = _once_more(lambda: ph.ping(port, dxl_id))
        _check(ph, result, error, f"ping ID {dxl_id} at {baud} baud")
        address, size, f = resolve_field(MODELS_BY_NUMBER.get(number), item, length)
        data, result, error = _once_more(lambda: ph.readTxRx(port, dxl_id, address, size))
        _check(ph, result, error, f"read ID {dxl_id} address {address} length {size}")
        return address, bytes(data), f


def write(path: str, dxl_id: int, item: str, value: int, baud: int, length: int | None = None,
          protocol: float = 2.0) -> tuple[int, Field | None]:
    """Write an item (by name or address) with the SDK; returns (address, field)."""
    ph = packet_handler(protocol)
    with open_port(path, baud) as port:
        number, result, error = _once_more(lambda: ph.ping(port, dxl_id))
        _check(ph, result, error, f"ping ID {dxl_id} at {baud} baud")
        address, size, f = resolve_field(MODELS_BY_NUMBER.get(number), item, length)
        signed = f.signed if f else value < 0
        try:
            data = list(int(value).to_bytes(size, "little", signed=signed))
        except OverflowError:
            kind = "a signed" if signed else "an unsigned"
            raise DxlRequestError(f"{value} does not fit in {size} byte(s) ({kind} item)") from None
        result, error = _once_more(lambda: ph.writeTxRx(port, dxl_id, address, size, data))
        _check(ph, result, error, f"write ID {dxl_id} address {address}")
        return address, f


def format_value(raw: bytes, f: Field | None) -> str:
    """``2048 (180.0 deg)`` for a known item, the integer for an unknown one."""
    if f is None:
        return str(int.from_bytes(raw, "little"))
    value = f.decode(raw[: f.size])
    if f.is_float:
        return f"{value:.4g} {f.unit}".rstrip()
    if f.unit and f.unit != "C" and f.scale != 1.0:
        return f"{value} ({f.physical(value):.4g} {f.unit})"
    if f.unit:
        return f"{value} {f.unit}"
    return str(value)
