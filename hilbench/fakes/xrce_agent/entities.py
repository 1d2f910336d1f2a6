"""The DDS entities a Micro XRCE-DDS client creates in the agent, from any representation (§1.8).

A CREATE names an object (12-bit id + kind) and represents it by reference (a
profile name the agent knows: the profile's ``refs``), as an XML string (the
Fast DDS profile syntax the client examples send) or in binary (what
``rmw_microxrcedds`` sends: the ``*_binary`` layouts of
:mod:`hilbench.protocols.xrce_dds`). Each becomes an :class:`Entity` with what
routing needs: parent, topic name, type name, reliability, history depth.
Matching (creation mode REUSE) compares those, as the agent compares
representations.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Any

from hilbench.protocols import xrce_dds as x

K = x.ObjectKind


@dataclass
class Entity:
    """One object of a client: ``parent`` is the raw id of its participant/publisher/subscriber."""

    object_id: bytes
    kind: int
    parent: bytes | None = None
    topic: str | None = None
    type_name: str | None = None
    reliable: bool | None = None
    depth: int = 1
    domain_id: int = 0
    name: str | None = None
    topic_id: bytes | None = None
    representation: tuple[int, Any] = (0, None)
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def kind_name(self) -> str:
        try:
            return K(self.kind).name.lower()
        except ValueError:
            return f"kind{self.kind}"

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"id": self.object_id.hex().upper(), "kind": self.kind_name}
        for key in ("topic", "type_name", "reliable", "name", "domain_id"):
            v = getattr(self, key)
            if v is not None and not (key == "domain_id" and self.kind != K.PARTICIPANT):
                out["type" if key == "type_name" else key] = v
        return out


class EntityError(ValueError):
    """A representation the agent cannot create; ``status`` is the XRCE result code to answer."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def _xml_find(root: ET.Element, *path: str) -> str | None:
    node: ET.Element | None = root
    for tag in path:
        if node is None:
            return None
        node = next((c for c in node.iter() if c.tag.split("}")[-1] == tag), None)
    return node.text.strip() if node is not None and node.text else None


def _parse_xml(text: str) -> ET.Element:
    try:
        return ET.fromstring(text.strip() or "<dds/>")
    except ET.ParseError as exc:
        raise EntityError(x.Status.ERR_INVALID_DATA, f"invalid XML: {exc}") from None


def _reliability(root: ET.Element, default: bool) -> bool:
    kind = _xml_find(root, "reliability", "kind")
    if kind is None:
        return default
    return kind.upper().startswith("RELIABLE")


def entity_from_create(object_id: bytes, rep: Any, le: bool, refs: dict[str, dict[str, Any]]) -> Entity:
    """An :class:`Entity` from a CREATE's ``object_representation`` (construct container); raises EntityError."""
    kind = rep.kind
    body = rep.rep
    ent = Entity(object_id, kind)
    if body is None:
        raise EntityError(x.Status.ERR_INVALID_DATA, f"cannot create objects of kind {kind}")
    if kind in (K.AGENT, K.CLIENT):
        raise EntityError(x.Status.ERR_INVALID_DATA, "agent and client objects are not created by CREATE")
    representation = body.representation
    fmt, value = representation.format, representation.value
    ent.representation = (fmt, value)
    for key in ("participant_id", "publisher_id", "subscriber_id"):
        if key in body:
            ent.parent = bytes(body[key])
    if kind == K.PARTICIPANT:
        ent.domain_id = body.domain_id
    if fmt == x.REPRESENTATION_BY_REFERENCE:
        ref = refs.get(str(value))
        if ref is None and kind != K.PARTICIPANT:
            raise EntityError(x.Status.ERR_UNKNOWN_REFERENCE, f"unknown reference {value!r}")
        ref = ref or {}
        ent.name = str(value)
        ent.topic = ref.get("topic")
        ent.type_name = ref.get("type")
        ent.reliable = ref.get("reliable")
        ent.depth = int(ref.get("depth", 1))
    elif fmt == x.REPRESENTATION_AS_XML:
        _from_xml(ent, str(value))
    elif fmt == x.REPRESENTATION_IN_BINARY:
        _from_binary(ent, bytes(value), le)
    else:
        raise EntityError(x.Status.ERR_INVALID_DATA, f"unknown representation format {fmt}")
    if ent.reliable is None and kind in (K.DATAWRITER, K.DATAREADER):
        # Fast DDS defaults: writers reliable, readers best-effort.
        ent.reliable = kind == K.DATAWRITER
    return ent


def _from_xml(ent: Entity, text: str) -> None:
    root = _parse_xml(text)
    if ent.kind == K.PARTICIPANT:
        ent.name = _xml_find(root, "name")
    elif ent.kind in (K.TOPIC, K.DATAWRITER, K.DATAREADER, K.REQUESTER, K.REPLIER):
        ent.topic = _xml_find(root, "topic", "name") or _xml_find(root, "name")
        ent.type_name = _xml_find(root, "topic", "dataType") or _xml_find(root, "dataType")
        depth = _xml_find(root, "historyQos", "depth") or _xml_find(root, "history", "depth")
        if depth and depth.isdigit():
            ent.depth = max(1, int(depth))
        if ent.kind in (K.DATAWRITER, K.DATAREADER):
            ent.reliable = _reliability(root, ent.kind == K.DATAWRITER)
        if ent.kind == K.TOPIC and not ent.topic:
            raise EntityError(x.Status.ERR_INVALID_DATA, "topic XML without a name")


def _from_binary(ent: Entity, blob: bytes, le: bool) -> None:
    kind = ent.kind
    try:
        if kind == K.PARTICIPANT:
            b = x.payload_layout("participant_binary", le).parse(blob)
            ent.name = b.qos_profile_reference or b.domain_reference
        elif kind == K.TOPIC:
            b = x.payload_layout("topic_binary", le).parse(blob)
            ent.topic, ent.type_name = b.topic_name, b.type_name or b.type_reference
        elif kind in (K.PUBLISHER, K.SUBSCRIBER):
            b = x.payload_layout("publisher_binary", le).parse(blob)
            ent.name = b.name
        elif kind in (K.DATAWRITER, K.DATAREADER):
            b = x.payload_layout("datawriter_binary" if kind == K.DATAWRITER else "datareader_binary",
                                 le).parse(blob)
            ent.topic_id = bytes(b.topic_id)
            if b.optional_qos:
                ent.reliable = bool(b.qos.base.qos_flags & x.QOS_RELIABLE)
                if b.qos.base.optional_history_depth:
                    ent.depth = max(1, b.qos.base.history_depth)
            else:
                ent.reliable = kind == K.DATAWRITER
        else:
            raise EntityError(x.Status.ERR_INVALID_DATA, f"no binary representation for kind {kind}")
    except EntityError:
        raise
    except Exception as exc:  # noqa: BLE001 (construct errors on a short or odd blob)
        raise EntityError(x.Status.ERR_INVALID_DATA, f"bad binary representation: {type(exc).__name__}") from None


def same(a: Entity, b: Entity) -> bool:
    """Whether two representations describe the same entity (creation mode REUSE)."""
    return (a.kind, a.parent, a.topic, a.type_name, a.reliable, a.topic_id, a.representation) == \
        (b.kind, b.parent, b.topic, b.type_name, b.reliable, b.topic_id, b.representation)


__all__ = ["Entity", "EntityError", "entity_from_create", "same"]
