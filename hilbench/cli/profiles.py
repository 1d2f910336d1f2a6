"""``hilbench profiles``: what profiles come bundled; ``profiles from-capture``: one from a capture."""

from __future__ import annotations

import argparse


def cmd_profiles(args: argparse.Namespace) -> int:
    import tomllib

    from hilbench.bench.profile import bundled_profiles
    from hilbench.profiles import DEFAULT_PROFILE

    # The list reads each profile's description only: checking every profile would load every family (the
    # bundled ones are checked by the tests; `hilbench emulate NAME` checks the one it runs).
    for name, path in sorted(bundled_profiles().items()):
        with open(path, "rb") as f:
            description = tomllib.load(f).get("description", "")
        marker = " (default)" if name == DEFAULT_PROFILE else ""
        print(f"{name}{marker}: {description}  [{path}]")
    return 0


ORDER = 70  # beside demo
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "profiles": "list the bundled profiles; from-capture: a profile from a capture of a real bus",
}


def register(sub: argparse._SubParsersAction) -> None:
    pr = sub.add_parser("profiles", help=VERBS["profiles"], description="List the bundled profiles, or write one "
                                                                       "from a capture (from-capture).")
    pr.set_defaults(func=cmd_profiles)
    from hilbench.cli.capture_profile import add_commands

    add_commands(pr)
