"""Hokuyo SCIP 2.0: request lines, replies (echo, status, data lines), 6-bit encodings and sums.

Wire layout (spec sheet laser_scanners.md §3)::

    request  CMD PARAMS [';' STRING] LF           (CR or CR LF accepted)
    reply    ECHO LF  STATUS(2) SUM LF  { DATA SUM LF }  LF
    SUM      chr((sum of the line's bytes & 0x3F) + 0x30); in KEY:VALUE;S lines the ';' is not summed
    data     6-bit characters (chr(v + 0x30)), 2, 3 or 4 per value; lines of at most 64 payload characters

Request parameters are fixed-width decimal ASCII; their construct layouts
(``ScanParams``, ``ContinuousParams``, made when first used) build and parse them. Replies
are built by :func:`reply` and parsed by :func:`parse_reply`;
:class:`ReplyDecoder` cuts a host's byte stream into replies (each ends with
an empty line) and :class:`RequestDecoder` a device's input into request
lines. Neither raises: bad sums and stray bytes become :class:`~hilbench.protocols.problem.Problem` s.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING, Any, NamedTuple

from hilbench.protocols.checksums import scip_sum
from hilbench.protocols.lazy_layouts import lazy_layouts
from hilbench.protocols.problem import Problem

LF = b"\n"
#: Data lines carry at most this many payload characters before their sum.
LINE_PAYLOAD = 64
#: A request line longer than this is answered 0D / dropped (bounded buffers).
MAX_LINE = 64
#: The 24-bit millisecond timestamp wraps here.
TIMESTAMP_WRAP = 1 << 24

STATUS_TEXT = {
    "00": "ok", "99": "scan data follows", "01": "parameter error 1", "02": "parameter error 2",
    "03": "parameter error 3", "04": "parameter error 4", "05": "parameter error 5", "06": "parameter error 6",
    "07": "parameter error 7", "0E": "undefined command", "0F": "command not supported", "0G": "string too long",
    "0H": "command too short", "0D": "command too long", "0L": "abnormal state", "0M": "unstable",
    "10": "denied / laser off",
}


if TYPE_CHECKING:  # (made by _layouts() when first used)
    from construct import Struct

    ScanParams: Struct
    ContinuousParams: Struct
    PARAMS: dict[str, Struct]


#: The construct layouts' names: module attributes, made when first used (:func:`_layouts`).
_LAYOUT_NAMES = ("ScanParams", "ContinuousParams", "PARAMS")


@cache
def _layouts() -> dict[str, Any]:
    """The construct layouts (``_LAYOUT_NAMES``), made with construct's import when first used: the decoders
    run without them until a frame needs one (the monitor asks every instrument about a capture's first
    bytes, and must not import construct for that)."""
    from construct import Adapter, Bytes, Struct

    class _Decimal(Adapter):
        """Fixed-width decimal ASCII digits <-> int."""

        def __init__(self, width: int) -> None:
            super().__init__(Bytes(width))
            self.width = width

        def _decode(self, obj, context, path):
            text = bytes(obj).decode("ascii")
            if not text.isdigit():
                raise ValueError(f"expected {self.width} digits, got {text!r}")
            return int(text)

        def _encode(self, obj, context, path):
            text = f"{int(obj):0{self.width}d}"
            if len(text) != self.width:
                raise ValueError(f"{obj} does not fit {self.width} digits")
            return text.encode("ascii")

    #: GD/GS/GE parameters: start step, end step, cluster count.
    ScanParams = Struct("start" / _Decimal(4), "end" / _Decimal(4), "cluster" / _Decimal(2))
    #: MD/MS/ME parameters: as GD, then skip count (1 digit) and scan count (2 digits, 00 = endless).
    ContinuousParams = Struct("start" / _Decimal(4), "end" / _Decimal(4), "cluster" / _Decimal(2),
                              "skip" / _Decimal(1), "scans" / _Decimal(2))
    #: Commands whose parameters hilbench parses, by code.
    PARAMS = {"GD": ScanParams, "GS": ScanParams, "GE": ScanParams,
              "MD": ContinuousParams, "MS": ContinuousParams, "ME": ContinuousParams}

    return {name: value for name, value in locals().items() if name in _LAYOUT_NAMES}


def layouts() -> None:
    """Make the construct layouts now (an emulator that builds its replies with them calls this when it is
    made, so that no client's first request waits for construct's import)."""
    _layouts()


__getattr__ = lazy_layouts(globals(), _LAYOUT_NAMES, _layouts)


#: Characters per value by command.
ENCODING = {"GD": 3, "GE": 3, "MD": 3, "ME": 3, "GS": 2, "MS": 2}
WITH_INTENSITY = ("GE", "ME")


# ----------------------------------------------------------------------------- encodings


def sum_char(line: bytes) -> bytes:
    """The sum character of a line's bytes."""
    return bytes([scip_sum(line)])


def encode(value: int, chars: int) -> bytes:
    """``value`` in ``chars`` 6-bit characters, most significant first."""
    return bytes(((value >> (6 * (chars - 1 - k))) & 0x3F) + 0x30 for k in range(chars))


def decode(text: bytes) -> int:
    """An integer from 6-bit characters."""
    v = 0
    for c in text:
        v = (v << 6) | ((c - 0x30) & 0x3F)
    return v


def encode_values(values: list[int] | Any, chars: int) -> bytes:
    """Many values, each in ``chars`` characters (vectorised with numpy for scans)."""
    import numpy as np

    v = np.asarray(values, dtype=np.int64)
    if v.size == 0:
        return b""
    shifts = np.arange(chars - 1, -1, -1) * 6
    out = ((v[:, None] >> shifts[None, :]) & 0x3F) + 0x30
    return out.astype(np.uint8).tobytes()


def decode_values(payload: bytes, chars: int) -> list[int]:
    """Values from a joined data payload (a trailing partial value is ignored)."""
    return [decode(payload[k:k + chars]) for k in range(0, len(payload) - chars + 1, chars)]


def data_lines(payload: bytes) -> bytes:
    """A data block cut into lines of at most 64 characters, each with its sum and LF."""
    out = bytearray()
    for k in range(0, len(payload), LINE_PAYLOAD):
        part = payload[k:k + LINE_PAYLOAD]
        out += part + sum_char(part) + LF
    return bytes(out)


def status_line(status: str) -> bytes:
    s = status.encode("ascii")
    return s + sum_char(s) + LF


def info_line(key: str, value: str) -> bytes:
    """A ``KEY:VALUE;S`` line; the ';' is not summed (what hokuyolx checks)."""
    kv = f"{key}:{value}".encode("ascii")
    return kv + b";" + sum_char(kv) + LF


def reply(echo: bytes, status: str, body: bytes = b"") -> bytes:
    """A whole reply: echo, status line, body lines (each already with sum and LF), closing LF."""
    return echo + LF + status_line(status) + body + LF


def timestamp_line(ms: int) -> bytes:
    t = encode(ms % TIMESTAMP_WRAP, 4)
    return t + sum_char(t) + LF


def request(cmd: str, params: dict[str, int] | str = "", string: str = "") -> bytes:
    """A request line; ``params`` as a dict is built with the command's construct layout."""
    p = _layouts()["PARAMS"][cmd].build(params).decode("ascii") if isinstance(params, dict) else params
    return f"{cmd}{p}{';' + string if string else ''}\n".encode("ascii")


# ----------------------------------------------------------------------------- parsing


class Request(NamedTuple):
    """A request line: the command code (2 chars, or 3 for ``%XX``), its parameter text and string."""

    cmd: str
    params: str
    string: str
    line: bytes  # without the terminator: what the echo repeats

    def fields(self) -> dict[str, int] | None:
        layout = _layouts()["PARAMS"].get(self.cmd)
        if layout is None:
            return None
        try:
            return dict((k, v) for k, v in layout.parse(self.params.encode("ascii")).items() if k != "_io")
        except Exception:  # noqa: BLE001 (a malformed request gets a status, never an exception)
            return None


class Reply(NamedTuple):
    """A parsed reply: echo line, status (2 chars, None if its sum failed), data lines' payloads."""

    echo: str
    status: str | None
    lines: list[bytes]
    bad_sums: int
    raw: bytes

    @property
    def cmd(self) -> str:
        return self.echo[:3] if self.echo.startswith("%") else self.echo[:2]

    def info(self) -> dict[str, str]:
        """KEY:VALUE pairs of a VV/PP/II reply (lines whose sum checks)."""
        out = {}
        for ln in self.lines:
            if b":" in ln:
                key, _, value = ln.partition(b":")
                out[key.decode("ascii", "replace")] = value.decode("ascii", "replace")
        return out

    def scan(self) -> tuple[int | None, list[int], list[int] | None]:
        """(timestamp ms, distances, intensities or None) of a GD/GS/GE/MD/MS/ME reply."""
        cmd = self.cmd
        chars = ENCODING.get(cmd, 3)
        if not self.lines:
            return None, [], None
        ts = decode(self.lines[0]) if len(self.lines[0]) == 4 else None
        payload = b"".join(self.lines[1:])
        values = decode_values(payload, chars)
        if cmd in WITH_INTENSITY:
            return ts, values[0::2], values[1::2]
        return ts, values, None


def parse_request(line: bytes) -> Request | None:
    """A request from one line (terminator stripped); None if it is not ASCII."""
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        return None
    body, _, string = text.partition(";")
    n = 3 if body.startswith("%") else 2
    return Request(body[:n], body[n:], string, line)


#: Replies made of ``KEY:VALUE;S`` lines.
INFO_COMMANDS = ("VV", "PP", "II")


def check_line(line: bytes, *, info: bool = False) -> bytes | None:
    """The payload of a summed line (None if the sum fails).

    ``info``: a ``KEY:VALUE;S`` line, whose sum may cover the ';' or not (urg_library accepts both);
    the ';' is then not part of the payload. In data lines ';' is an ordinary 6-bit character.
    """
    if len(line) < 2:
        return None
    payload, s = line[:-1], line[-1]
    if not info:
        return payload if scip_sum(payload) == s else None
    if not payload.endswith(b";"):
        return None
    if scip_sum(payload[:-1]) == s or scip_sum(payload) == s:
        return payload[:-1]
    return None


def parse_reply(raw: bytes) -> Reply:
    """A reply from its bytes (ending in LF LF); never raises."""
    text = raw[:-2] if raw.endswith(b"\n\n") else raw.rstrip(b"\n")
    lines = text.split(b"\n")
    echo = lines[0].decode("ascii", "replace")
    status = None
    bad = 0
    if len(lines) > 1:
        st = check_line(lines[1])
        if st is not None and len(st) == 2:
            status = st.decode("ascii", "replace")
        else:
            bad += 1
    payloads = []
    info = echo[:2] in INFO_COMMANDS
    for ln in lines[2:]:
        p = check_line(ln, info=info)
        if p is None:
            bad += 1
            continue
        payloads.append(p)
    return Reply(echo, status, payloads, bad, bytes(raw))


class RequestDecoder:
    """Cuts a device's input into request lines (LF, CR or CR LF); bounded, never raises."""

    def __init__(self, max_line: int = 256) -> None:
        self._buf = bytearray()
        self.max_line = max_line
        self.dropped = 0
        self._skip_lf = False

    def reset(self) -> None:
        """Forget a request line begun but not ended (a new connection starts with an empty buffer)."""
        self.dropped += len(self._buf)
        self._buf.clear()
        self._skip_lf = False

    def feed(self, data: bytes) -> list[Request | Problem]:
        out: list = []
        for b in data:
            if self._skip_lf:
                self._skip_lf = False
                if b == 0x0A:
                    continue
            if b in (0x0A, 0x0D):
                self._skip_lf = b == 0x0D
                line = bytes(self._buf)
                self._buf.clear()
                req = parse_request(line)
                if req is None:
                    self.dropped += len(line)
                    out.append(Problem("garbage", line))
                else:
                    out.append(req)
                continue
            if len(self._buf) >= self.max_line:
                self.dropped += 1
                if not out or not isinstance(out[-1], Problem) or out[-1].kind != "overlong":
                    out.append(Problem("overlong", bytes(self._buf[:16]), "request line too long"))
                continue
            self._buf.append(b)
        return out


class ReplyDecoder:
    """Cuts a host's input (what a SCIP sensor sends) into replies at each empty line; never raises."""

    def __init__(self, max_reply: int = 1 << 16) -> None:
        self._buf = bytearray()
        self.max_reply = max_reply
        self.dropped = 0
        self.bad_sums = 0

    def feed(self, data: bytes) -> list[Reply | Problem]:
        buf = self._buf
        buf += data
        out: list = []
        while True:
            # A reply never starts with LF: stray empty lines are dropped.
            k = 0
            while k < len(buf) and buf[k] == 0x0A:
                k += 1
            if k:
                self.dropped += k
                del buf[:k]
            end = buf.find(b"\n\n")
            if end < 0:
                break
            raw = bytes(buf[:end + 2])
            del buf[:end + 2]
            rep = parse_reply(raw)
            self.bad_sums += rep.bad_sums
            out.append(rep)
        if len(buf) > self.max_reply:
            self.dropped += len(buf)
            out.append(Problem("overlong", bytes(buf[:64]), f"{len(buf)} bytes without an end"))
            buf.clear()
        return out


__all__ = [
    "ENCODING", "INFO_COMMANDS", "LF", "LINE_PAYLOAD", "MAX_LINE", "PARAMS", "STATUS_TEXT", "TIMESTAMP_WRAP", "WITH_INTENSITY",
    "ContinuousParams", "Reply", "ReplyDecoder", "Request", "RequestDecoder", "ScanParams",
    "check_line", "data_lines", "decode", "decode_values", "encode", "encode_values", "info_line", "layouts",
    "parse_reply", "parse_request", "reply", "request", "status_line", "sum_char", "timestamp_line",
]
