"""``hilbench plugins``: what this installation can emulate, open and watch, and which package says so."""

from __future__ import annotations

import argparse
import json
import re

from hilbench import registry
from hilbench.errors import UsageError

ORDER = 90
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "plugins": "list the device families, bus kinds, endpoint types, sources, instruments, verbs and fuzz targets",
}


def _describe(kind: registry.Kind, name: str, obj) -> str:
    if kind is registry.families:
        return f"joins {', '.join(obj.joins)}; {len(obj.models)} models ({', '.join(obj.models[:3])}, ...)" \
            if len(obj.models) > 3 else f"joins {', '.join(obj.joins)}; models {', '.join(obj.models)}"
    if kind is registry.bus_kinds:
        return f"{obj.medium} medium; endpoints {', '.join(obj.endpoint_types)}"
    if kind is registry.instruments:
        return f"{obj.title or obj.protocol} (hilbench {obj.verb})"
    if kind is registry.sources:
        return obj.usage or obj.what
    if kind is registry.fuzz_targets:
        return f"{obj.title} ({obj.kind})"
    if kind is registry.inferrers:
        return f"{obj.title or name}: profiles from {', '.join(obj.protocols)} captures"
    doc = (getattr(obj, "__doc__", None) or "").strip().splitlines()
    # the first docstring line, without reST markup (:attr:`x` -> x, ``y`` -> y)
    return re.sub(r":\w+:`~?([^`]+)`|``([^`]+)``", lambda m: m[1] or m[2], doc[0]) if doc else ""


def _rows(kind: registry.Kind):
    """``{"name", "package", "what"}`` of each plug-in of ``kind`` as it is loaded, then its failures."""
    for name in kind.names():
        try:
            obj = kind.get(name)  # (one entry point at a time: the listing shows while the rest load)
        except UsageError:
            continue  # (listed with the failures)
        yield {"name": name, "package": kind.origin(name), "what": _describe(kind, name, obj)}
    for name, why in kind.failures().items():
        yield {"name": name, "package": why.split(":")[0], "what": f"FAILED: {why}"}


def cmd_plugins(args: argparse.Namespace) -> int:
    if args.json:
        print(json.dumps({kind.name: list(_rows(kind)) for kind in registry.KINDS}, indent=2))
        return 0
    for kind in registry.KINDS:
        print(f"{kind.name}  [entry points: {kind.group}]", flush=True)
        width = max([14, *(len(n) for n in kind.names())])  # (fuzz targets' names run longer)
        for e in _rows(kind):
            print(f"  {e['name']:<{width}} {e['package']:<18} {e['what']}", flush=True)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help=VERBS["plugins"],
                       description="List every plug-in this installation has (hilbench's own and other packages' "
                                   "entry points) and the package that registered it; plug-ins that failed to "
                                   "load are listed with the reason.")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_plugins)
