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

from dataclasses import dataclass, field
from typing import Any

from hilbench.errors import RequestRefused
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
        if self.kind in (K.REQUESTER, K.REPLIER):
            out.update({k: v for k, v in self.extra.items() if v is not None})
        return out


class EntityError(RequestRefused, ValueError):
    """A representation the agent cannot create; ``status`` is the XRCE result code to answer."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


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
    ent.representation = (representation.format, representation.value)
    info = x.representation_info(kind, body, le)
    if "error" in info:
        raise EntityError(x.Status.ERR_INVALID_DATA, f"unreadable {info.get('format')} representation: "
                                                    f"{info['error']}")
    ent.parent = info.get("parent")
    ent.domain_id = info.get("domain_id", 0)
    ent.topic_id = info.get("topic_id")
    ent.name = info.get("name")
    if info.get("format") == "ref":
        ref = refs.get(str(representation.value))
        if ref is None:
            # The agent's middleware finds no such profile: the creation fails (ERR_DDS_ERROR).
            raise EntityError(x.Status.ERR_DDS_ERROR, f"unknown reference {representation.value!r}")
        ent.topic, ent.type_name, ent.reliable = ref.get("topic"), ref.get("type"), ref.get("reliable")
        ent.depth = int(ref.get("depth", 1))
        if kind in (K.REQUESTER, K.REPLIER) and ref.get("service"):
            info.update({"service": ref["service"], "request_type": ref.get("request_type"),
                         "reply_type": ref.get("reply_type")})
            info["request_topic"], info["reply_topic"] = x.service_topics(
                ref["service"], ref.get("request_topic"), ref.get("reply_topic"))
    elif info.get("format") in ("xml", "binary"):
        ent.topic, ent.type_name = info.get("topic"), info.get("type")
        ent.reliable = info.get("reliable")
        ent.depth = max(1, int(info.get("depth", 1)))
        if kind == K.TOPIC and not ent.topic:
            raise EntityError(x.Status.ERR_INVALID_DATA, "topic without a name")
    else:
        raise EntityError(x.Status.ERR_INVALID_DATA, f"unknown representation format {representation.format}")
    if kind in (K.REQUESTER, K.REPLIER):
        if not info.get("service"):
            raise EntityError(x.Status.ERR_INVALID_DATA, f"{ent.kind_name} without a service name")
        for key in ("service", "request_topic", "request_type", "reply_topic", "reply_type"):
            ent.extra[key] = info.get(key)
        ent.reliable = True  # Fast DDS requesters and repliers are reliable
    if ent.reliable is None and kind in (K.DATAWRITER, K.DATAREADER):
        # Fast DDS defaults: writers reliable, readers best-effort.
        ent.reliable = kind == K.DATAWRITER
    return ent


def same(a: Entity, b: Entity) -> bool:
    """Whether two representations describe the same entity (creation mode REUSE)."""
    return (a.kind, a.parent, a.topic, a.type_name, a.reliable, a.topic_id, a.representation) == \
        (b.kind, b.parent, b.topic, b.type_name, b.reliable, b.topic_id, b.representation)


__all__ = ["Entity", "EntityError", "entity_from_create", "same"]
