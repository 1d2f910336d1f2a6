"""A running bench's traffic tap, found through the manifest ``hilbench emulate --manifest`` wrote."""

from __future__ import annotations

import json
from pathlib import Path
from urllib.parse import urlparse

from hilbench.transports.sources.base import Source, SourceError, SourceOpener


def _manifest_tap(path: Path, endpoint: str | None) -> tuple[str, str]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise SourceError(f"{path}: not a bench manifest ({exc})") from None
    eps = data.get("endpoints") if isinstance(data, dict) else None
    if not isinstance(eps, list):
        raise SourceError(f"{path}: not a bench manifest (no endpoints)")
    if endpoint is not None:
        eps = [e for e in eps if e.get("name") == endpoint]
        if not eps:
            raise SourceError(f"{path}: no endpoint named {endpoint!r}")
    for ep in eps:
        if ep.get("tap"):
            return ep["tap"], f"{path}#{ep.get('name')}"
    raise SourceError(f"{path}: the bench offers no tap (started with --no-tap?)")


def open_manifest(spec: str, target: str, fragment: str, **_: object) -> Source:
    from hilbench.transports.sources.stream import TcpSource

    tap, name = _manifest_tap(Path(target), fragment or None)
    tap_url = urlparse(tap)
    return TcpSource(tap_url.hostname or "127.0.0.1", tap_url.port or 0, name=name)


MANIFEST = SourceOpener("manifest", open_manifest, suffixes=(".json",), usage="/tmp/bench.json[#endpoint]",
                        what="the traffic tap of a running hilbench emulate, found through its manifest")

__all__ = ["MANIFEST", "open_manifest"]
