"""Recording a running bench's line while clients drive it, and inferring a profile back from the recording."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hilbench.bench.capture_profile import (
    InferOptions,
    ProfileDraft,
    SourceFacts,
    check_profile_text,
    infer,
    protocol_source,
    render,
    traffic_of,
)
from hilbench.transports.capture_file import CaptureWriter
from hilbench.transports.chunk import Chunk
from hilbench.transports.sources import open_source


@contextlib.contextmanager
def recording(endpoint: Any, path: Path) -> Iterator[Path]:
    """Record ``endpoint``'s medium into ``path``: a hilbench capture, or a python-can log for ``.log``/``.asc``
    names (as ``hilbench record`` writes them)."""
    if path.suffix in (".log", ".asc"):
        from hilbench.transports.can_log import CanLogRecorder

        rec = CanLogRecorder(str(path), wall_offset=time.time() - time.monotonic())

        def tap(t: float, source: str, data: bytes, *_: Any) -> None:
            rec.chunk(Chunk(t, source, data))
    else:
        rec = CaptureWriter(path, baud=endpoint.spec.baud, protocol=endpoint.medium.protocol or endpoint.spec.protocol,
                            description=f"test recording of {endpoint.name}")

        def tap(t: float, source: str, data: bytes, *_: Any) -> None:
            rec.write(t, source, data)

    endpoint.medium.add_tap(tap)
    try:
        yield path
    finally:
        endpoint.medium.remove_tap(tap)
        rec.close()


def infer_file(path: Path | str, *, baud: int | None = None, protocol: str | None = None,
               keep_silent: bool = False) -> tuple[ProfileDraft, SourceFacts, str]:
    """The draft, facts and TOML text ``profiles from-capture`` makes of a capture file (checked to load)."""
    with open_source(str(path), baud=baud) as source:
        told, rivals = protocol_source(source, protocol), []
        traffic, source = traffic_of(source, protocol, rivals=rivals)
        draft, facts = infer(source, traffic, baud=baud, baud_from="--baud" if baud else "", protocol_from=told,
                             rivals=rivals,
                             options=InferOptions(keep_silent=keep_silent))
    text = render(draft, facts, command="test")
    check_profile_text(text)
    return draft, facts, text
