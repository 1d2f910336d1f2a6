"""``hilbench plugins``: what this installation can emulate, open and watch, and which package says so."""

from __future__ import annotations

import argparse
import json
import re

from hilbench import registry

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


def cmd_plugins(args: argparse.Namespace) -> int:
    rows = {}
    for kind in registry.KINDS:
        rows[kind.name] = [{"name": name, "package": kind.origin(name), "what": _describe(kind, name, obj)}
                           for name, obj in kind.items()]
        failed = kind.failures()
        if failed:
            rows[kind.name] += [{"name": n, "package": why.split(":")[0], "what": f"FAILED: {why}"}
                                for n, why in failed.items()]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for kind, entries in rows.items():
        print(f"{kind}  [entry points: {getattr(registry, kind).group}]")
        width = max([14, *(len(e["name"]) for e in entries)])  # (fuzz targets' names run longer)
        for e in entries:
            print(f"  {e['name']:<{width}} {e['package']:<18} {e['what']}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help=VERBS["plugins"],
                       description="List every plug-in this installation has (hilbench's own and other packages' "
                                   "entry points) and the package that registered it; plug-ins that failed to "
                                   "load are listed with the reason.")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_plugins)
