"""``hilbench labgrid``: publish a served bench to labgrid (exporter configuration, environment file)."""

from __future__ import annotations

import argparse

ORDER = 75
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "labgrid": "publish a served bench to labgrid (exporter config, environment)",
}


def cmd_exporter_config(args: argparse.Namespace) -> int:
    from hilbench.labgrid.config import dump, exporter_config, load_manifest

    _check_output(args)
    manifest = load_manifest(args.manifest)
    data = exporter_config(manifest, host=args.host)
    group = manifest["name"]
    comment = (f"labgrid exporter configuration of hilbench bench {group!r} ({args.manifest}).\n"
               f"Run: labgrid-exporter -c COORDINATOR:20408 -n EXPORTER THIS_FILE\n"
               f"(add --isolated when clients on other machines reach {group!r} through SSH).\n"
               f"Place: labgrid-client -p PLACE create; labgrid-client -p PLACE add-match 'EXPORTER/{group}/*'")
    _write(args.output, dump(data, comment))
    return 0


def cmd_env(args: argparse.Namespace) -> int:
    from hilbench.labgrid.config import dump, environment, load_manifest

    _check_output(args)
    manifest = load_manifest(args.manifest)
    data = environment(manifest, host=args.host, target=args.target)
    comment = (f"labgrid environment of hilbench bench {manifest['name']!r} ({args.manifest}), no coordinator needed.\n"
               "Use: labgrid.Environment(THIS_FILE).get_target(); pytest --lg-env THIS_FILE [--hilbench-labgrid]")
    _write(args.output, dump(data, comment))
    return 0


def _check_output(args: argparse.Namespace) -> None:
    """Refuse ``-o`` onto the manifest read (or into no directory) before anything is read."""
    from hilbench.cli.outputs import check_outputs

    check_outputs([("-o", args.output)], inputs=[args.manifest])


def _write(output: str | None, text: str) -> None:
    """To stdout, or replacing ``output`` in one step (a full disk leaves an old file whole)."""
    from hilbench.cli.outputs import write_output

    write_output(output, text)


def register(sub: argparse._SubParsersAction) -> None:
    lg = sub.add_parser("labgrid", help=VERBS["labgrid"],
                        description="Write labgrid configuration for a bench started with "
                                    "`hilbench emulate PROFILE --serve rfc2217 --manifest FILE`. Serial endpoints "
                                    "become NetworkSerialPort resources (protocol rfc2217, speed = the endpoint's "
                                    "baud); traffic taps and the control channel NetworkSerialPort (protocol raw).")
    verbs = lg.add_subparsers(dest="labgrid_verb", required=True, metavar="WHAT")
    for name, func, help_text in (
        ("exporter-config", cmd_exporter_config,
         "labgrid-exporter configuration: the bench's resources in a group named after the bench"),
        ("env", cmd_env, "labgrid environment (target with resources and drivers) for use without a coordinator"),
    ):
        v = verbs.add_parser(name, help=help_text, description=help_text)
        v.add_argument("manifest", help="the bench's manifest (hilbench emulate --manifest FILE)")
        v.add_argument("-o", "--output", metavar="FILE", help="write to FILE (default: standard output)")
        v.add_argument("--host", metavar="HOST",
                       help="host name or address clients use (default: where the bench listens, 127.0.0.1; "
                            "with labgrid-exporter --isolated clients reach it through SSH)")
        if name == "env":
            v.add_argument("--target", default="main", help="target name (default: main)")
        v.set_defaults(func=func)
