"""Signal decoders for the CAN monitor: a DBC (or KCD, SYM, ARXML) through cantools, an EDS through canopen.

A decoder names frames and turns their bytes into signal values; the
tracker asks every decoder it has, first answer wins. :func:`load_dbc`
also takes the name of a bench profile with CANopen boards (the DBC
``hilbench can dbc PROFILE`` exports), so ``--dbc mecarover-can`` decodes
an emulated bench without a file (the profile is read by the device family that
describes its boards, not here).

Both libraries are the optional ``can`` extra (``pip install 'hilbench[can]'``);
without them these decoders say so in one line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hilbench.errors import UsageError, require
from hilbench.protocols.can_frame import CanFrame


class Decoder:
    """Names and decodes frames; subclasses implement what their file knows."""

    source = ""

    def name(self, frame: CanFrame) -> str | None:
        return None

    def decode(self, frame: CanFrame) -> dict[str, Any] | None:
        """Signal values (physical, with units applied) or None if it does not know the frame; may raise."""
        return None

    def object_name(self, node: int, index: int, subindex: int) -> str | None:
        return None


class DbcDecoder(Decoder):
    """A cantools database."""

    def __init__(self, db: Any, source: str) -> None:
        self.db = db
        self.source = source
        self._by_id: dict[tuple[int, bool], Any] = {}
        for m in db.messages:
            self._by_id[(m.frame_id, bool(m.is_extended_frame))] = m

    def _message(self, frame: CanFrame) -> Any:
        return self._by_id.get((frame.can_id, frame.extended))

    def name(self, frame: CanFrame) -> str | None:
        m = self._message(frame)
        return m.name if m is not None else None

    def units(self, frame: CanFrame) -> dict[str, str]:
        m = self._message(frame)
        return {s.name: s.unit or "" for s in m.signals} if m is not None else {}

    def decode(self, frame: CanFrame) -> dict[str, Any] | None:
        m = self._message(frame)
        if m is None or frame.remote:
            return None
        values = m.decode(frame.data, decode_choices=True, scaling=True)
        return {k: (str(v) if not isinstance(v, int | float) else v) for k, v in values.items()}


def _cantools():
    return require("cantools", "can", "decoding with a DBC")


def load_dbc(spec: str) -> DbcDecoder:
    """A DBC/KCD/SYM/ARXML file, or a bench profile whose boards a family describes; UsageError in one line.

    A profile is resolved through the device families (a family with CAN boards offers the artefact
    ``"dbc"``: :meth:`~hilbench.bench.family.DeviceFamily.artefact`), so the monitor knows no family.
    """
    cantools = _cantools()
    path = Path(spec)
    if path.suffix.lower() in (".dbc", ".kcd", ".sym", ".arxml", ".json") or (path.exists() and path.suffix != ".toml"):
        try:
            return DbcDecoder(cantools.database.load_file(str(path), strict=False), str(path))
        except FileNotFoundError:
            raise UsageError(f"{spec}: no such database file") from None
        except Exception as exc:
            raise UsageError(f"{spec}: cannot load it as a CAN database: {str(exc).splitlines()[0]}") from None
    from hilbench import registry

    for family in registry.families.find(lambda f: "dbc" in f.artefacts):
        text = family.artefact("dbc", spec)
        if text:
            return DbcDecoder(cantools.database.load_string(text, "dbc", strict=False), f"{spec} (profile)")
    raise UsageError(f"{spec}: neither a CAN database file nor a profile with CAN boards")


class EdsDecoder(Decoder):
    """An EDS for node ``node``: object names for SDO transfers, and its PDOs decoded by their default mapping."""

    def __init__(self, od: Any, node: int, source: str) -> None:
        from canopen.objectdictionary import ODRecord

        self.od = od
        self.node = node
        self.source = source
        self.pdos: dict[int, tuple[str, list[Any]]] = {}
        for comm_base, map_base, word in ((0x1800, 0x1A00, "TPDO"), (0x1400, 0x1600, "RPDO")):
            for k in range(512):
                comm, mapping = od.get(comm_base + k), od.get(map_base + k)
                if comm is None or mapping is None or not isinstance(comm, ODRecord):
                    continue
                try:
                    cob_id = comm[1].default
                    count = mapping[0].default or 0
                    entries = [mapping[i].default for i in range(1, count + 1)]
                except (KeyError, TypeError):
                    continue
                if cob_id is None or cob_id & 0x80000000:
                    continue
                variables = []
                for word32 in entries:
                    if word32 is None:
                        break
                    index, sub = word32 >> 16, (word32 >> 8) & 0xFF
                    try:
                        obj = od[index]
                        variables.append(obj if sub == 0 and not isinstance(obj, ODRecord) else obj[sub])
                    except KeyError:
                        variables = []
                        break
                if variables:
                    self.pdos[cob_id & 0x7FF] = (f"{word}{k + 1}", variables)

    def name(self, frame: CanFrame) -> str | None:
        pdo = self.pdos.get(frame.can_id) if not frame.extended else None
        return pdo[0] if pdo else None

    def decode(self, frame: CanFrame) -> dict[str, Any] | None:
        pdo = self.pdos.get(frame.can_id) if not frame.extended else None
        if pdo is None or frame.remote:
            return None
        out: dict[str, Any] = {}
        offset = 0
        for var in pdo[1]:
            size = len(var)
            if size % 8:
                raise ValueError(f"{var.name}: {size}-bit objects are not decoded")
            chunk = frame.data[offset // 8 : (offset + size) // 8]
            if len(chunk) * 8 != size:
                raise ValueError(f"{pdo[0]} is {len(frame.data)} bytes, its mapping needs more")
            raw = var.decode_raw(chunk)
            value = raw * var.factor if isinstance(raw, int | float) and var.factor not in (None, 1) else raw
            parent = getattr(var, "parent", None)
            out[f"{parent.name}.{var.name}" if parent is not None else var.name] = value
            offset += size
        return out

    def object_name(self, node: int, index: int, subindex: int) -> str | None:
        if node != self.node:
            return None
        obj = self.od.get(index)
        if obj is None:
            return None
        try:
            from canopen.objectdictionary import ODVariable

            if isinstance(obj, ODVariable):
                return obj.name
            return f"{obj.name}.{obj[subindex].name}"
        except KeyError:
            return obj.name


def load_eds(spec: str) -> EdsDecoder:
    """``FILE:NODE`` (an EDS or DCF and the node it describes); UsageError in one line."""
    canopen = require("canopen", "can", "decoding with an EDS")
    path, sep, node_text = spec.rpartition(":")
    if not sep or not node_text.isdigit() or not 1 <= int(node_text) <= 127:
        raise UsageError(f"--eds {spec}: give the node the file describes: --eds FILE:NODE (node 1..127)")
    node = int(node_text)
    if not Path(path).exists():
        raise UsageError(f"{path}: no such EDS file")
    try:
        od = canopen.import_od(path, node)
    except Exception as exc:
        raise UsageError(f"{path}: cannot import it as an EDS: {str(exc).splitlines()[0] if str(exc) else exc!r}") \
            from None
    return EdsDecoder(od, node, path)


__all__ = ["DbcDecoder", "Decoder", "EdsDecoder", "load_dbc", "load_eds"]
