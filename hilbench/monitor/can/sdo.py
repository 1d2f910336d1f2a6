"""Following SDO transfers on the wire (the client's requests and the server's responses of one node).

:class:`SdoFollower` is fed the frames of 0x600+n and 0x580+n in bus order
and yields each finished transfer (:class:`SdoTransfer`): expedited or
segmented, upload (read) or download (write), its bytes (the first
:data:`MAX_KEPT` of them) or the abort that ended it. Block transfers are
recognised by their command specifier and reported when they are aborted (or
left as ``block`` when the node ends them another way). Never raises on
strange frames; they are counted.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from hilbench.protocols import canopen as co

#: Bytes of a transfer's value kept for the summary.
MAX_KEPT = 64


@dataclass
class SdoTransfer:
    """One SDO transfer seen on the bus."""

    node: int
    index: int
    subindex: int
    upload: bool
    t_start: float
    t_end: float | None = None
    segmented: bool = False
    block: bool = False
    size: int | None = None
    data: bytearray = field(default_factory=bytearray)
    received: int = 0
    abort: int = 0
    aborted_by: str = ""  # "server" or "client"

    @property
    def direction(self) -> str:
        return "upload" if self.upload else "download"

    @property
    def kind(self) -> str:
        return "block" if self.block else "segmented" if self.segmented else "expedited"

    def value(self) -> int | str | None:
        """The value as a number (1..4 bytes, little-endian) or text (printable), else None."""
        raw = bytes(self.data)
        if not raw or self.abort:
            return None
        if len(raw) <= 4 and not self.segmented:
            return int.from_bytes(raw, "little")
        if all(32 <= b < 127 for b in raw):
            return raw.decode("ascii")
        return None


class SdoFollower:
    """The SDO channel of one node, followed from both directions."""

    def __init__(self, node: int) -> None:
        self.node = node
        self.current: SdoTransfer | None = None
        self._last_segment = False
        self.unexpected = 0

    def request(self, data: bytes, t: float) -> SdoTransfer | None:
        """A client frame (0x600+n); returns a transfer it ended (a client abort), if any."""
        if not data:
            self.unexpected += 1
            return None
        data = bytes(data[:8]).ljust(8, b"\0")
        cs = co.specifier(data[0])
        if cs in (co.CCS_INITIATE_DOWNLOAD, co.CCS_INITIATE_UPLOAD, co.CCS_BLOCK_UPLOAD, co.CCS_BLOCK_DOWNLOAD):
            command, index, subindex, payload = co.parse_initiate(data)
            upload = cs in (co.CCS_INITIATE_UPLOAD, co.CCS_BLOCK_UPLOAD)
            tr = SdoTransfer(self.node, index, subindex, upload, t, block=cs in (co.CCS_BLOCK_UPLOAD,
                                                                                 co.CCS_BLOCK_DOWNLOAD))
            if cs == co.CCS_INITIATE_DOWNLOAD:
                if command & 0x02:
                    tr.data += payload[: co.expedited_size(command)]
                    tr.size = len(tr.data)
                else:
                    tr.segmented = True
                    if command & 0x01:
                        tr.size = struct.unpack("<I", payload)[0]
            self.current = tr
            self._last_segment = False
            return None
        if cs == co.CCS_DOWNLOAD_SEGMENT:
            tr = self.current
            if tr is None or tr.upload:
                self.unexpected += 1
                return None
            n = (data[0] >> 1) & 7
            self._keep(tr, data[1 : 8 - n])
            self._last_segment = bool(data[0] & 1)
            return None
        if cs == co.CCS_UPLOAD_SEGMENT:
            if self.current is None or not self.current.upload:
                self.unexpected += 1
            return None
        if cs == co.CCS_ABORT:
            tr = self.current
            _cmd, index, subindex, payload = co.parse_initiate(data)
            if tr is None:
                tr = SdoTransfer(self.node, index, subindex, False, t)
            tr.abort = struct.unpack("<I", payload)[0]
            tr.aborted_by = "client"
            return self._finish(tr, t)
        self.unexpected += 1
        return None

    def response(self, data: bytes, t: float) -> SdoTransfer | None:
        """A server frame (0x580+n); returns the transfer it completed, if any."""
        if not data:
            self.unexpected += 1
            return None
        data = bytes(data[:8]).ljust(8, b"\0")
        cs = co.specifier(data[0])
        tr = self.current
        if cs == co.SCS_ABORT:
            _cmd, index, subindex, payload = co.parse_initiate(data)
            if tr is None:
                tr = SdoTransfer(self.node, index, subindex, False, t)
            tr.abort = struct.unpack("<I", payload)[0]
            tr.aborted_by = "server"
            return self._finish(tr, t)
        if tr is None:
            self.unexpected += 1
            return None
        if cs == co.SCS_INITIATE_DOWNLOAD and not tr.upload:
            return None if tr.segmented else self._finish(tr, t)
        if cs == co.SCS_DOWNLOAD_SEGMENT and not tr.upload:
            return self._finish(tr, t) if self._last_segment else None
        if cs == co.SCS_INITIATE_UPLOAD and tr.upload:
            command, _index, _sub, payload = co.parse_initiate(data)
            if command & 0x02:
                tr.data += payload[: co.expedited_size(command)]
                tr.size = len(tr.data)
                return self._finish(tr, t)
            tr.segmented = True
            if command & 0x01:
                tr.size = struct.unpack("<I", payload)[0]
            return None
        if cs == co.SCS_UPLOAD_SEGMENT and tr.upload and tr.segmented:
            n = (data[0] >> 1) & 7
            self._keep(tr, data[1 : 8 - n])
            return self._finish(tr, t) if data[0] & 1 else None
        if cs in (co.SCS_BLOCK_DOWNLOAD, co.SCS_BLOCK_UPLOAD) and tr.block:
            return None  # block sub-protocols are not followed further
        self.unexpected += 1
        return None

    @staticmethod
    def _keep(tr: SdoTransfer, chunk: bytes) -> None:
        tr.received += len(chunk)
        room = MAX_KEPT - len(tr.data)
        if room > 0:
            tr.data += chunk[:room]

    def _finish(self, tr: SdoTransfer, t: float) -> SdoTransfer:
        tr.t_end = t
        if tr.segmented and tr.size is None:
            tr.size = tr.received
        self.current = None
        self._last_segment = False
        return tr


__all__ = ["MAX_KEPT", "SdoFollower", "SdoTransfer"]
