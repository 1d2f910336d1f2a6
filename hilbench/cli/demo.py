"""``hilbench demo`` and ``hilbench profiles``: the main job, and what profiles come bundled."""

from __future__ import annotations

import argparse

from hilbench.profile import DEFAULT_PROFILE, bundled_profiles, load_profile


def cmd_demo(args: argparse.Namespace) -> int:
    from hilbench.demo import run_demo

    result = run_demo(args.profile, args.seconds, paced=not args.unpaced)
    print(f"\ndemo: {result.cycles} control cycles in {result.seconds:.1f} s ({result.rate:.0f}/s), "
          f"{result.failed_reads} failed reads")
    return 0 if result.cycles else 1


def cmd_profiles(args: argparse.Namespace) -> int:
    for name, path in sorted(bundled_profiles().items()):
        prof = load_profile(path)
        marker = " (default)" if name == DEFAULT_PROFILE else ""
        print(f"{name}{marker}: {prof.description}  [{path}]")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    dm = sub.add_parser("demo", help="run the default bench and drive it with the official SDK, live",
                        description="Start a bench and run a Sync Read / Sync Write control loop against it "
                                    "with the official dynamixel-sdk, showing what it reads.")
    dm.add_argument("--profile", default=DEFAULT_PROFILE, help=f"profile (default: {DEFAULT_PROFILE})")
    dm.add_argument("--seconds", type=float, default=10.0, help="how long to run (0: until Ctrl-C; default 10)")
    dm.add_argument("--unpaced", action="store_true", help="deliver bytes at once instead of at wire speed")
    dm.set_defaults(func=cmd_demo)

    pr = sub.add_parser("profiles", help="list the bundled profiles", description="List the bundled profiles.")
    pr.set_defaults(func=cmd_profiles)
