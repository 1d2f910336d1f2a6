"""Bench manifests: the JSON file ``hilbench emulate --manifest`` writes so other programs find the bench."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def write_manifest(path: str | Path, data: dict[str, Any]) -> None:
    """Write a manifest atomically (readers never see half a file)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)


__all__ = ["write_manifest"]
