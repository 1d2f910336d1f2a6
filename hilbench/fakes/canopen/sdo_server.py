"""A CANopen SDO server (CiA 301): expedited and segmented transfers over an object dictionary.

:meth:`SdoServer.request` takes the 8 bytes a client sent to 0x600+n and
returns the 8-byte response for 0x580+n (or None: an abort from the client
is not answered). Block transfers are refused with abort 0x05040001
(command specifier not valid), which makes clients such as the ``canopen``
package fall back to segmented transfers; so does a segment out of turn.
Toggle errors abort with 0x05030000, a segmented download whose length
differs from the size it announced with 0x06070010.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from hilbench.fakes.canopen.dictionary import ObjectDictionary
from hilbench.protocols import canopen as co
from hilbench.protocols.canopen_od import type_size

#: Largest value a segmented download may carry (bounded: a size field never drives allocation).
MAX_DOWNLOAD = 4096


@dataclass
class _Transfer:
    upload: bool
    index: int
    subindex: int
    toggle: int = 0
    data: bytearray = field(default_factory=bytearray)
    size: int | None = None
    pos: int = 0


@dataclass
class SdoLogEntry:
    """One finished transfer, for the node's status: what, which way, how big, how it ended."""

    index: int
    subindex: int
    upload: bool
    size: int
    segmented: bool
    abort: int = 0


class SdoServer:
    """The server side of the default SDO channel of one node."""

    def __init__(self, dictionary: ObjectDictionary) -> None:
        self.od = dictionary
        self._transfer: _Transfer | None = None
        self.uploads = 0
        self.downloads = 0
        self.aborts_sent = 0
        self.aborts_received = 0
        self.forced_abort = 0  # a fault knob: answer every request with this abort code
        self.log: list[SdoLogEntry] = []

    def _done(self, entry: SdoLogEntry) -> None:
        self.log.append(entry)
        del self.log[:-32]

    def _abort(self, index: int, subindex: int, code: int) -> bytes:
        self._transfer = None
        self.aborts_sent += 1
        self._done(SdoLogEntry(index, subindex, False, 0, False, code))
        return co.sdo_abort(index, subindex, code)

    def request(self, data: bytes) -> bytes | None:
        """Answer one request (short requests are padded to 8 bytes as zeros)."""
        data = bytes(data[:8]).ljust(8, b"\0")
        command = data[0]
        cs = co.specifier(command)
        if cs == co.CCS_ABORT:
            self._transfer = None
            self.aborts_received += 1
            return None
        if cs in (co.CCS_INITIATE_DOWNLOAD, co.CCS_INITIATE_UPLOAD, co.CCS_BLOCK_UPLOAD, co.CCS_BLOCK_DOWNLOAD):
            _cmd, index, subindex, payload = co.parse_initiate(data)
            if self.forced_abort:
                return self._abort(index, subindex, self.forced_abort)
            if cs == co.CCS_INITIATE_UPLOAD:
                return self._initiate_upload(index, subindex)
            if cs == co.CCS_INITIATE_DOWNLOAD:
                return self._initiate_download(command, index, subindex, payload)
            return self._abort(index, subindex, co.ABORT_COMMAND)  # block transfers are not served
        transfer = self._transfer
        if cs == co.CCS_UPLOAD_SEGMENT and transfer is not None and transfer.upload:
            return self._upload_segment(transfer, (command >> 4) & 1)
        if cs == co.CCS_DOWNLOAD_SEGMENT and transfer is not None and not transfer.upload:
            return self._download_segment(transfer, command, data[1:8])
        index, subindex = (transfer.index, transfer.subindex) if transfer else (0, 0)
        return self._abort(index, subindex, co.ABORT_COMMAND)

    # ------------------------------------------------------------------ upload (read)

    def _initiate_upload(self, index: int, subindex: int) -> bytes:
        value = self.od.read(index, subindex)
        if isinstance(value, int):
            return self._abort(index, subindex, value)
        if 0 < len(value) <= 4:
            self._transfer = None
            self.uploads += 1
            self._done(SdoLogEntry(index, subindex, True, len(value), False))
            return co.expedited_upload_response(index, subindex, value)
        self._transfer = _Transfer(True, index, subindex, data=bytearray(value))
        # Segmented: size indicated (s = 1, e = 0).
        return co.initiate(0x41, index, subindex, struct.pack("<I", len(value)))

    def _upload_segment(self, t: _Transfer, toggle: int) -> bytes:
        if toggle != t.toggle:
            return self._abort(t.index, t.subindex, co.ABORT_TOGGLE)
        chunk = bytes(t.data[t.pos : t.pos + 7])
        t.pos += len(chunk)
        last = t.pos >= len(t.data)
        response = co.segment(toggle, chunk, last, server=True)
        t.toggle ^= 1
        if last:
            self._transfer = None
            self.uploads += 1
            self._done(SdoLogEntry(t.index, t.subindex, True, len(t.data), True))
        return response

    # ------------------------------------------------------------------ download (write)

    def _initiate_download(self, command: int, index: int, subindex: int, payload: bytes) -> bytes:
        expedited = bool(command & 0x02)
        if expedited:
            value = payload[: co.expedited_size(command)]
            if not command & 0x01:  # size not indicated: the object's own size
                var = self.od.lookup(index, subindex)
                if not isinstance(var, int):
                    size = type_size(var.data_type)
                    value = payload[:size] if size is not None else payload
            code = self.od.write(index, subindex, value)
            if code:
                return self._abort(index, subindex, code)
            self._transfer = None
            self.downloads += 1
            self._done(SdoLogEntry(index, subindex, False, len(value), False))
            return co.initiate(0x60, index, subindex)
        var = self.od.lookup(index, subindex)
        if isinstance(var, int):
            return self._abort(index, subindex, var)
        if var.access in ("ro", "const"):
            return self._abort(index, subindex, co.ABORT_READ_ONLY)
        size = struct.unpack("<I", payload)[0] if command & 0x01 else None
        if size is not None and size > MAX_DOWNLOAD:
            return self._abort(index, subindex, co.ABORT_TOO_LONG)
        self._transfer = _Transfer(False, index, subindex, size=size)
        return co.initiate(0x60, index, subindex)

    def _download_segment(self, t: _Transfer, command: int, chunk: bytes) -> bytes:
        toggle = (command >> 4) & 1
        if toggle != t.toggle:
            return self._abort(t.index, t.subindex, co.ABORT_TOGGLE)
        n = (command >> 1) & 7
        t.data += chunk[: 7 - n]
        if len(t.data) > MAX_DOWNLOAD:
            return self._abort(t.index, t.subindex, co.ABORT_TOO_LONG)
        t.toggle ^= 1
        response = bytes([0x20 | (toggle << 4)]) + bytes(7)
        if command & 0x01:  # last segment
            if t.size is not None and t.size != len(t.data):
                return self._abort(t.index, t.subindex, co.ABORT_LENGTH)
            code = self.od.write(t.index, t.subindex, bytes(t.data))
            if code:
                return self._abort(t.index, t.subindex, code)
            self._transfer = None
            self.downloads += 1
            self._done(SdoLogEntry(t.index, t.subindex, False, len(t.data), True))
        return response

    def reset(self) -> None:
        """Forget a transfer in progress (the node was reset)."""
        self._transfer = None


__all__ = ["SdoLogEntry", "SdoServer"]
