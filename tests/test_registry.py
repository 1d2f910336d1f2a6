"""The plug-in registry: built-ins come from entry points, broken plug-ins are skipped with a warning,
the core knows no family by name."""

from __future__ import annotations

import re
import subprocess
import sys
import tokenize
from pathlib import Path

import pytest

from hilbench import registry
from hilbench.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
#: The generic modules: none of them may name a device family or its protocol.
CORE = [
    "hilbench/registry.py", "hilbench/errors.py", "hilbench/bench/bench.py", "hilbench/bench/profile.py",
    "hilbench/bench/bus.py", "hilbench/bench/family.py",
    "hilbench/bench/checks.py", "hilbench/bench/manifest.py", "hilbench/bench/control.py",
    "hilbench/cli/__init__.py", "hilbench/cli/common.py", "hilbench/cli/emulate.py", "hilbench/cli/monitor.py",
    "hilbench/monitor/live.py", "hilbench/monitor/detect.py", "hilbench/monitor/instrument.py",
    "hilbench/dashboard/app.py", "hilbench/transports/medium.py", "hilbench/transports/host_port.py",
    *[f"hilbench/transports/sources/{m}.py" for m in ("__init__", "base", "file", "serial", "stream", "udp")],
]
DOCSTRING = re.compile(r"^[rRuU]?('''|\"\"\")")


def test_builtins_are_registered_through_entry_points_like_any_package():
    assert {"dynamixel", "stm32-rover"} <= set(registry.families)
    assert registry.families.origin("dynamixel") == "hilbench"  # from the metadata, not from code
    assert {"dynamixel", "vel2d", "can"} <= set(registry.bus_kinds)
    assert registry.family_for_model("MX-64").name == "dynamixel"
    assert [f.name for f in registry.families_joining("can")] == ["canopen"]
    assert {"pty", "udp", "tcp"} <= set(registry.host_ports)
    assert "serial" in registry.media
    assert {"file", "stdin", "serial", "fifo", "tcp", "udp", "manifest"} <= set(registry.sources)
    assert registry.instrument_for("dynamixel").verb == "monitor"
    assert registry.instrument_for("vel2d").verb == "trace"
    assert {"emulate", "monitor", "trace", "plugins"} <= set(registry.verbs)


@pytest.mark.parametrize("path", CORE)
def test_the_core_names_no_family(path):
    """No identifier, import path or plain string of a generic module is a family's or protocol's name
    (docstrings and comments may give examples; a word in a message is not a name)."""
    names = {n for fam in registry.families.values() for n in (fam.name, *fam.joins)} | set(registry.bus_kinds)
    names |= {n.replace("-", "_") for n in names} | {"servo", "rover", "board", "stm32", "dxl", "dynamixel"}
    found = set()
    with tokenize.open(ROOT / path) as fh:
        for tok in tokenize.generate_tokens(fh.readline):
            if tok.type == tokenize.NAME and tok.string.lower() in names:
                found.add(tok.string)
            elif tok.type == tokenize.STRING and not DOCSTRING.match(tok.string):
                value = tok.string.lstrip("frbuFRBU").strip("'\"")
                if value.lower() in names or any(f"families.{n}" in value or f"{n}." in value.split(":")[0]
                                                 for n in names if n not in ("can",)):
                    found.add(value)
    assert not found, f"{path} names {sorted(found)}"


def test_a_broken_plugin_is_skipped_with_one_warning(tmp_path, monkeypatch):
    dist = tmp_path / "broken_lab_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-lab-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[hilbench.families]\nacme = no_such_module:FAMILY\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.reload()
    try:
        assert "acme" in registry.families.names()  # names are read without loading anything
        with pytest.warns(registry.PluginWarning, match="acme.*broken-lab-plugin.*skipped"):
            names = [name for name, _ in registry.families.items()]
        assert "acme" not in names and "dynamixel" in names
        assert "acme" not in registry.families.names() and "acme" not in registry.families  # known to fail now
        assert "ModuleNotFoundError" in registry.families.failures()["acme"]
        with pytest.raises(UsageError, match="device family 'acme' could not be loaded .*ModuleNotFoundError"):
            registry.families.get("acme")
    finally:
        monkeypatch.undo()
        registry.reload()
    assert registry.families.failures() == {}


LAZY = """
import sys
from hilbench import registry
before = set(sys.modules)
names = registry.instruments.names()
assert "dynamixel" in registry.instruments and "can" in names, names
assert not {m for m in set(sys.modules) - before if m.startswith("hilbench.monitor")}, "names() loaded a plug-in"
registry.instruments.get("dynamixel")
loaded = {m for m in set(sys.modules) - before if m.startswith("hilbench.monitor")}
assert "hilbench.monitor.dynamixel" in loaded, loaded
assert not {m for m in loaded if m.startswith(("hilbench.monitor.can", "hilbench.monitor.udp"))}, loaded
order = [name for name, _ in registry.instruments.items()]
assert order == sorted(order) and order[0] != "dynamixel", order  # by name, not in the order they loaded
print("ok")
"""


def test_names_load_nothing_and_get_loads_the_one_asked_for():
    proc = subprocess.run([sys.executable, "-c", LAZY], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and proc.stdout == "ok\n", proc.stderr


def test_plugins_verb_lists_every_kind():
    proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "plugins"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0
    for kind in registry.KINDS:
        assert f"[entry points: {kind.group}]" in proc.stdout
    assert re.search(r"^  dynamixel\s+hilbench\s+joins dynamixel; \d+ models", proc.stdout, re.M)
    assert re.search(r"^  can\s+hilbench\s+can medium; endpoints can", proc.stdout, re.M)


def test_each_verb_module_names_the_verbs_it_registers():
    import argparse

    declared = {name: module for name, module in registry.verbs.items() if hasattr(module, "VERBS")}
    assert {"emulate", "monitor", "dxl", "send-vel", "teleop"} <= set(declared)
    for name, module in declared.items():  # one entry point per verb, each naming the module that adds it
        assert name in module.VERBS or "." in name, name
        assert set(module.VERBS) <= set(declared), name
    for name, module in declared.items():
        sub = argparse.ArgumentParser().add_subparsers()
        module.register(sub)
        assert set(sub.choices) == set(module.VERBS), name
        # `hilbench --help` shows VERBS' lines: the same as the full parser's
        assert {a.dest: a.help for a in sub._choices_actions} == module.VERBS, name


LOADED = """
import sys
from hilbench.cli import build_parser
parser = build_parser(sys.argv[1:])
print(sorted(parser._subparsers._group_actions[0].choices), "dpkt" in sys.modules)
"""


def test_a_command_registers_only_its_own_verbs_and_help_lists_them_all_from_their_help_lines():
    def loaded(*argv: str) -> str:
        proc = subprocess.run([sys.executable, "-c", LOADED, *argv], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.strip()

    # `hilbench dxl ...` does not load the monitor's sources and instruments (dpkt among them) for help texts,
    # and neither does the list of verbs
    assert loaded("dxl", "ping", "/dev/null") == "['dxl'] False"
    assert loaded("send-vel", "--help") == "['board', 'send-vel', 'teleop'] False"  # the rover family's verbs
    assert loaded("monitor", "x.hbcap") == "['monitor', 'record', 'tap'] False"  # dpkt: once a pcap is read
    full = loaded("--help")
    assert "'emulate'" in full and "'monitor'" in full and "'teleop'" in full and full.endswith("False")
    assert loaded("emulat") == full  # a typo: every verb, for argparse's list of choices


def test_an_extension_adds_sub_commands_to_its_verb_only():
    from hilbench.cli import build_parser

    ext = type(sys)("acme_can_extension")
    ext.extend = lambda subs: subs.add_parser("acme", help="an extension's sub-command").set_defaults(acme=True)
    registry.verbs.register("can.acme", ext)  # as an entry point named can.acme would
    try:
        args = build_parser(["can", "acme"]).parse_args(["can", "acme"])
        assert args.acme is True
        with pytest.raises(SystemExit):  # another verb does not get it
            build_parser(["dxl", "acme"]).parse_args(["dxl", "acme"])
        assert "can.acme" not in build_parser(["--help"])._subparsers._group_actions[0].choices  # not a verb
    finally:
        registry.verbs.unregister("can.acme")


def test_an_unknown_name_is_a_usage_error_naming_the_known_ones():
    with pytest.raises(UsageError, match=r"unknown endpoint type 'serial9' \(known: .*pty"):
        registry.host_ports.get("serial9")
    with pytest.raises(UsageError, match=r"unknown bus kind 'canbus' \(known: can, "):
        registry.bus_kinds.get("canbus")
    assert registry.family_for_model("XM999") is None



CLASHING_PLUGIN = '''
from hilbench.bench.bus import BusKind
from hilbench.bench.family import DeviceFamily


class AcmeFamily(DeviceFamily):
    name = "acme"
    models = ("acme-1", "MX-64")  # the second is a Dynamixel model
    joins = ("dynamixel",)


class AcmeBus(BusKind):
    protocol = "dynamixel"  # the Dynamixel bus kind's protocol


FAMILY = AcmeFamily()
BUS_KIND = AcmeBus()
'''


def test_a_clashing_plugin_is_skipped_with_a_warning_naming_both_packages(tmp_path, monkeypatch):
    (tmp_path / "acme_clash.py").write_text(CLASHING_PLUGIN)
    dist = tmp_path / "acme_lab_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-lab-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[hilbench.families]\nacme = acme_clash:FAMILY\n\n"
                                           "[hilbench.bus_kinds]\nacme-bus = acme_clash:BUS_KIND\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.reload()
    try:
        with pytest.warns(registry.PluginWarning) as caught:
            families = [name for name, _ in registry.families.items()]
            kinds = [name for name, _ in registry.bus_kinds.items()]
        messages = [str(w.message) for w in caught]
        assert ("hilbench: device family 'acme' from acme-lab-plugin skipped: its model 'MX-64' is taken by device "
                "family 'dynamixel' (from hilbench)") in messages
        assert ("hilbench: bus kind 'acme-bus' from acme-lab-plugin skipped: its protocol 'dynamixel' is taken by bus "
                "kind 'dynamixel' (from hilbench)") in messages
        assert "acme" not in families and "acme-bus" not in kinds
        assert registry.family_for_model("MX-64").name == "dynamixel"  # the first registered keeps it
        assert "clashes" in registry.families.failures()["acme"]
    finally:
        monkeypatch.undo()
        registry.reload()
    assert registry.families.failures() == {} and registry.bus_kinds.failures() == {}


def test_a_clashing_registration_in_code_raises():
    from hilbench.bench.bus import BusKind
    from hilbench.bench.family import DeviceFamily
    from hilbench.families.rplidar import RplidarFamily

    class Acme(DeviceFamily):
        name = "acme"
        models = ("acme-1", "lms200")  # the SICK LMS 200's model

    with pytest.raises(ValueError, match=r"device family 'acme' clashes: its model 'lms200' is taken by device "
                                         r"family 'sick-lms200' \(from hilbench\)"):
        registry.families.register("acme", Acme())
    with pytest.raises(ValueError, match="device family 'dynamixel' is registered already"):
        registry.families.register("dynamixel", Acme())
    assert "acme" not in registry.families

    class CanAgain(BusKind):
        protocol = "can"

    with pytest.raises(ValueError, match="bus kind 'can2' clashes: its protocol 'can' is taken by bus kind 'can'"):
        registry.bus_kinds.register("can2", CanAgain())

    class Defaults(DeviceFamily):
        name = "defaults"
        default_keys = {"supply_voltage": (0, 1, 0)}  # the Dynamixel family's [defaults] key

    with pytest.raises(ValueError, match=r"its \[defaults\] key 'supply_voltage' is taken by device family 'dynamixel'"):
        registry.families.register("defaults", Defaults())

    class OwnScene(DeviceFamily):  # a [scene] table checked another way
        name = "own-scene"
        profile_tables = ("scene",)

    with pytest.raises(ValueError, match=r"its profile table 'scene' is taken by device family 'rplidar'"):
        registry.families.register("own-scene", OwnScene())

    class SameScene(RplidarFamily):  # the same table, checked by the same function: shared
        name = "same-scene"
        models = ("another-lidar",)

    registry.families.register("same-scene", SameScene())
    try:
        assert registry.family_for_model("another-lidar").name == "same-scene"
    finally:
        registry.families.unregister("same-scene")
    assert "another-lidar" not in {m for f in registry.families.values() for m in f.models}

    verb = type(sys)("acme_verb")
    verb.VERBS = {"emulate": "clashes with hilbench's own verb"}
    with pytest.raises(ValueError, match="its verb 'emulate' is taken by verb module 'emulate'"):
        registry.verbs.register("acme-verb", verb)

    instrument = type("Inst", (), {"protocol": "acme", "aliases": ("canopen",)})()
    with pytest.raises(ValueError, match="its protocol 'canopen' is taken by instrument 'can'"):
        registry.instruments.register("acme", instrument)
