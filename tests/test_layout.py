"""The package's layout rules, read from the source (AST, no imports of the modules checked):

- no import cycles between modules (an import inside a function counts: it runs the other module's body);
- no layer imports a higher one (DESIGN.md §2: protocols -> transports -> fakes / instruments -> presentation
  -> bench -> families -> surfaces);
- no shared module names a device family (a family's name, bus protocol or model as a string, or an import
  of a module the family owns): a family touches only its own files (issue 24).

The last two keep a list of today's exceptions, each with its reason; the steps of issue 24 empty them. The
lists are exact: a new violation fails, and so does an entry nothing needs any more (delete it then).
"""

from __future__ import annotations

import ast
import collections
import fnmatch
import functools
import re
from dataclasses import dataclass, field
from pathlib import Path

from hilbench import registry

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "hilbench"
#: A string that names a module for importlib (``RuleRef("hilbench.families.x", ...)``, ``"hilbench.x:NAME"``).
MODULE_STRING = re.compile(r"^(hilbench(?:\.\w+)+)(?::[\w.]+)?$")


@dataclass
class Module:
    name: str  # hilbench.monitor.dynamixel
    rel: str  # monitor/dynamixel/__init__.py (relative to hilbench/)
    imports: set[str] = field(default_factory=set)  # run when the module or one of its functions runs
    type_only: set[str] = field(default_factory=set)  # under `if TYPE_CHECKING:`
    strings: set[str] = field(default_factory=set)  # module names in string constants (imported by importlib)
    constants: set[str] = field(default_factory=set)  # every string constant but docstrings


def _docstrings(tree: ast.Module) -> set[int]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                found.add(id(first.value))
    return found


class _Reader(ast.NodeVisitor):
    """Collects one module's imports and string constants into its :class:`Module`."""

    def __init__(self, mod: Module, package: str, known: dict[str, Module], docs: set[int]) -> None:
        self.mod, self.package, self.known, self.docs = mod, package, known, docs
        self.into = mod.imports

    def resolve(self, name: str) -> str | None:
        while name and name not in self.known:
            name = name.rpartition(".")[0]
        return name if name and name != self.mod.name else None

    def visit_If(self, node: ast.If) -> None:
        if "TYPE_CHECKING" not in ast.unparse(node.test):
            self.generic_visit(node)
            return
        outer, self.into = self.into, self.mod.type_only
        for child in node.body:
            self.visit(child)
        self.into = outer
        for child in node.orelse:
            self.visit(child)

    def visit_Import(self, node: ast.Import) -> None:
        self.add([a.name for a in node.names])

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        base = node.module or ""
        if node.level:
            parts = self.package.split(".")
            base = ".".join(parts[:len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
        self.add([f"{base}.{a.name}" if f"{base}.{a.name}" in self.known else base for a in node.names])

    def visit_Constant(self, node: ast.Constant) -> None:
        if isinstance(node.value, str) and id(node) not in self.docs:
            self.mod.constants.add(node.value)
            if (m := MODULE_STRING.match(node.value)) and (target := self.resolve(m.group(1))):
                self.mod.strings.add(target)

    def add(self, names: list[str]) -> None:
        for name in names:
            if name.startswith("hilbench") and (target := self.resolve(name)):
                self.into.add(target)


@functools.cache
def modules() -> dict[str, Module]:
    """Every module of the package, by dotted name, with what it imports and the strings it holds."""
    paths = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        paths[".".join(parts)] = path
    found = {name: Module(name, path.relative_to(PACKAGE).as_posix()) for name, path in paths.items()}
    for name, path in paths.items():
        tree = ast.parse(path.read_text(), str(path))
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        _Reader(found[name], package, found, _docstrings(tree)).visit(tree)
    return found


# -- import cycles ------------------------------------------------------------------------------------------

def import_graph() -> dict[str, set[str]]:
    """Module -> modules its import runs: its imports (in functions too, not under TYPE_CHECKING) and the
    packages above each (importing ``a.b.c`` runs ``a/__init__`` and ``a/b/__init__`` first)."""
    graph = {}
    for name, mod in modules().items():
        edges = set(mod.imports)
        for target in mod.imports:
            parent = target.rpartition(".")[0]
            while parent.startswith("hilbench"):
                if parent != name and not name.startswith(parent + "."):
                    edges.add(parent)
                parent = parent.rpartition(".")[0]
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """Strongly connected components of more than one module (Tarjan's, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(frozenset(component))
    return found


def shortest_cycle(graph: dict[str, set[str]], component: frozenset[str]) -> list[str]:
    best: list[str] = []
    for start in sorted(component):
        prev: dict[str, str | None] = {start: None}
        queue = collections.deque([start])
        while queue:
            node = queue.popleft()
            if start in graph[node]:
                path = [node]
                while prev[path[-1]] is not None:
                    path.append(prev[path[-1]])
                path = [*reversed(path), start]
                if not best or len(path) < len(best):
                    best = path
                break
            for child in sorted(graph[node] & component):
                if child not in prev:
                    prev[child] = node
                    queue.append(child)
    return best


def test_the_cycle_finder_finds_a_cycle_and_only_cycles():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e"}}
    assert cycles(graph) == [frozenset({"a", "b", "c"})]
    assert shortest_cycle(graph, frozenset({"a", "b", "c"})) == ["a", "b", "c", "a"]


def test_no_import_cycles():
    """None at all: a module that needs another's types for annotations only imports them under
    ``TYPE_CHECKING``; a base class two modules share lives in a third (``transports/can_door.py``)."""
    graph = import_graph()
    found = [" -> ".join(shortest_cycle(graph, c)) for c in cycles(graph)]
    assert not found, f"import cycles: {found}"


# -- layers -------------------------------------------------------------------------------------------------

#: DESIGN.md §2, as the package is laid out. A module may import its own layer's and lower layers' modules.
#: Layers of one rank are siblings that do not import each other (fakes and instruments; families and the
#: bench's servers). The base is what every layer may use: errors, value rules, the registry (it loads
#: plug-ins by name, importing none of them), fuzz-target types, the console.
LAYERS: dict[str, tuple[int, set[str]]] = {
    "base": (0, {"hilbench", "hilbench.errors", "hilbench.rules", "hilbench.registry",
                 "hilbench.fuzzing", "hilbench.console"}),
    "protocols": (1, {"hilbench.protocols"}),
    "transports": (2, {"hilbench.transports"}),
    "fakes": (3, {"hilbench.fakes"}),
    "instruments": (3, {"hilbench.monitor", "hilbench.profiler"}),
    "presentation": (4, {"hilbench.dashboard"}),
    "bench": (5, {"hilbench.bench"}),
    "families": (6, {"hilbench.families"}),
    # plug-ins of the bench (`--serve rfc2217`), like families
    "servers": (6, {"hilbench.servers"}),
    # host-side drivers the verbs use (SDK connections, scanner drivers, the demo's loop, teleop)
    "clients": (7, {"hilbench.clients"}),
    # the CLI, the pytest plugin, `hilbench run`'s machinery, the labgrid drivers and config
    "surfaces": (8, {"hilbench.cli", "hilbench.pytest_plugin", "hilbench.run", "hilbench.labgrid"}),
}

#: Imports that go up or sideways today, (importer, imported) -> why (none when this was written).
UPWARD_EXCEPTIONS: dict[tuple[str, str], str] = {}


def layer_of(module: str) -> str:
    best = ("", "")
    for layer, (_, prefixes) in LAYERS.items():
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > len(best[1]):
                best = (layer, prefix)
    assert best[0], f"{module} is in no layer of LAYERS: add its package"
    return best[0]


def test_every_module_is_in_one_layer():
    for name in modules():
        layer_of(name)


def test_no_upward_imports():
    """Counts every import (in functions and under TYPE_CHECKING too). A module named in a string is not
    counted: an instrument names its dashboard views (``views_path``) for the dashboard to import."""
    found = {}
    for name, mod in modules().items():
        mine = layer_of(name)
        for target in mod.imports | mod.type_only:
            theirs = layer_of(target)
            if theirs != mine and LAYERS[theirs][0] >= LAYERS[mine][0]:
                found[(name, target)] = f"{mine} imports {theirs}"
    new = {k: v for k, v in found.items() if k not in UPWARD_EXCEPTIONS}
    assert not new, f"imports up or sideways: {new}"
    gone = set(UPWARD_EXCEPTIONS) - set(found)
    assert not gone, f"delete from UPWARD_EXCEPTIONS, these imports are gone: {sorted(gone)}"


# -- a family touches only its own files --------------------------------------------------------------------

#: The files each built-in family owns (globs under hilbench/). Everything else is shared: the frame, the
#: kits families build on (families/scanner.py, families/servo_bus.py, fakes/scanners/{base,uart}.py,
#: fakes/{scene,control_table_servo,table_servo,motion,servo_bus,xrce_client}.py, fakes/canopen/{node,dictionary,
#: sdo_server}.py, protocols/{control_table,canopen,canopen_od,cdr}.py, monitor/scanners/{__init__,tracker}.py,
#: clients/{base,scanners}.py, ...) and the generic instruments (the CAN, UDP and trace instruments) and verbs.
OWNED: dict[str, tuple[str, ...]] = {
    "dynamixel": ("protocols/dynamixel*.py", "fakes/dynamixel/*", "families/dynamixel.py", "families/dynamixel_*.py",
                  "monitor/dynamixel/*", "monitor/dynamixel1/*", "dashboard/dynamixel_views.py", "clients/dynamixel.py",
                  "cli/dynamixel.py", "labgrid/dynamixel.py"),
    "feetech": ("protocols/feetech*.py", "fakes/feetech/*", "families/feetech.py", "families/feetech_*.py",
                "monitor/feetech/*"),
    "stm32-rover": ("protocols/vel2d*.py", "protocols/tracestamp*.py", "fakes/stm32_board/*",
                    "families/stm32_rover*.py", "cli/stm32_rover.py"),
    "rplidar": ("protocols/rplidar*.py", "fakes/scanners/rplidar.py", "families/rplidar*.py",
                "monitor/scanners/rplidar*.py", "clients/rplidar.py"),
    "sick-lms200": ("protocols/sick_lms200*.py", "fakes/scanners/sick_lms200.py", "families/sick_lms200*.py",
                    "monitor/scanners/sick_lms200*.py", "clients/sick_lms200.py"),
    "scip2": ("protocols/scip*.py", "fakes/scanners/scip.py", "families/scip2*.py", "monitor/scanners/scip2*.py",
              "clients/scip2.py"),
    "canopen": ("protocols/board_can.py", "fakes/canopen/rover.py", "fakes/canopen/recorded.py",
                "families/canopen_*.py", "clients/can_rover.py"),
    "micro-ros-agent": ("protocols/xrce_dds.py", "fakes/xrce_agent/*", "families/micro_ros_agent*.py",
                        "monitor/udp/xrce_state.py"),
    "freertps": ("protocols/rtps.py", "fakes/rtps_node/*", "families/freertps.py", "monitor/udp/rtps_state.py"),
}
#: Words of a family beyond its name, the bus protocols it joins and models: its other instruments' protocols.
EXTRA_WORDS = {"dynamixel": {"dynamixel1"}}
#: Bus protocols that are a transport's, not a family's: "can" is also the CAN host port and medium.
GENERIC_WORDS = {"can"}

#: Shared modules that name a family today (PLAN24 §1), module -> {what it names}; the steps of issue 24
#: (P5, P8a-d, P11 in PLAN24 §10) empty it. An import of a family's protocol codec is not counted:
#: codecs are libraries anyone may use (DESIGN.md §3); a string naming it (its protocol) is.
NAMES_A_FAMILY: dict[str, set[str]] = {
    # P8c: the CANopen board's subcommands become the verb extension cli/canopen_board.py
    "cli/can.py": {"'canopen'", "import hilbench.clients.can_rover", "import hilbench.families.canopen_board"},
    # P8c: --view choices from the servo bus's instrument
    "cli/demo.py": {"'dynamixel'", "import hilbench.dashboard.dynamixel_views"},
    # P8c: the trace instrument's device_sources and default_baud
    "cli/trace.py": {"'stm32f767-rover'", "'vel2d'"},
    # P8c: servo clients from the registry (clients/servo_demo.py, clients/{dynamixel,feetech}.py)
    "clients/dynamixel_demo.py": {"'Wolfgang Foot'", "'dynamixel'", "'feetech'"},
    "clients/servo_connections.py": {"'dynamixel'", "'dynamixel1'", "'feetech'", "import hilbench.clients.dynamixel"},
    # family -> family: the Protocol 1.0 bus core and tracker into a servo-bus kit (PLAN24 §1, "should")
    "fakes/feetech/bus.py": {"import hilbench.fakes.dynamixel.bus1"},
    "monitor/feetech/__init__.py": {"import hilbench.monitor.dynamixel1"},
    "monitor/feetech/dialect.py": {"import hilbench.monitor.dynamixel.devices", "import hilbench.monitor.dynamixel1.tracker"},
    # family -> family: the shared RTPS part into a kit (families/rtps_kit.py, PLAN24 §1, "should")
    "families/micro_ros_agent.py": {"import hilbench.families.freertps"},
    "fakes/xrce_agent/bridge.py": {"import hilbench.fakes.rtps_node.participant"},
    # not in PLAN24 §1: the CANopen board drives the rover board's robot model (a robot kit would hold it)
    "fakes/canopen/rover.py": {"import hilbench.fakes.stm32_board.robot"},
    # not in PLAN24 §1: the generic CANopen node package re-exports the board's node (importing the kit
    # loads the rover model)
    "fakes/canopen/__init__.py": {"import hilbench.fakes.canopen.rover"},
    # not in PLAN24 §1: the CAN instrument's alias names the family ("monitor --protocol canopen")
    "monitor/can/__init__.py": {"'canopen'"},
    # not in PLAN24 §1: the UDP instrument classifies XRCE-DDS, RTPS and Vel2d datagrams itself (families
    # should contribute their classifiers and states)
    "monitor/udp/__init__.py": {"'rtps'", "'xrce-dds'"},
    "monitor/udp/classify.py": {"'rtps'", "'vel2d'"},
    "monitor/udp/summary.py": {"'rtps'"},
    "monitor/udp/tracker.py": {"import hilbench.monitor.udp.rtps_state", "import hilbench.monitor.udp.xrce_state"},
    "dashboard/udp_views.py": {"'rtps'"},
    # not in PLAN24 §1: the trace profiler is registered for the rover board's bus protocol and names the
    # board in its Perfetto export (P8c moves the trace instrument's defaults, P9 renames the verb `trace`)
    "profiler/instrument.py": {"'vel2d'"},
    "profiler/export_perfetto.py": {"'stm32f767-rover'"},
}
#: Strings equal to a family's word that name something else, for good: a third-party package that shares
#: the family's name (``require("canopen", ...)`` imports python-canopen, not the family).
NOT_A_FAMILY: dict[str, set[str]] = {
    "monitor/can/decoders.py": {"'canopen'"},
}


def owner(rel: str) -> str | None:
    for family, globs in OWNED.items():
        if any(fnmatch.fnmatchcase(rel, g) for g in globs):
            return family
    return None


def family_words() -> dict[str, set[str]]:
    """word -> the built-in families it names (name, bus protocols it joins, models, EXTRA_WORDS)."""
    words: dict[str, set[str]] = collections.defaultdict(set)
    for name, family in registry.families.items():
        if registry.families.origin(name) != "hilbench":
            continue
        for word in {name, *family.joins, *family.models, *EXTRA_WORDS.get(name, ())} - GENERIC_WORDS:
            words[word].add(name)
    return words


def test_every_built_in_family_says_which_files_it_owns():
    builtin = {n for n in registry.families.names() if registry.families.origin(n) == "hilbench"}
    assert builtin == set(OWNED)
    rels = [mod.rel for mod in modules().values()]
    for family, globs in OWNED.items():
        for pattern in globs:
            assert any(fnmatch.fnmatchcase(rel, pattern) for rel in rels), f"{family}: {pattern} matches no file"


def test_no_shared_module_names_a_family():
    """A module names family F if it holds a string equal to F's name, a bus protocol or model of F (not in a
    docstring), or imports (or names for importlib) a module F owns, unless F owns the module itself."""
    words = family_words()
    mods = modules()
    found: dict[str, set[str]] = collections.defaultdict(set)
    for mod in mods.values():
        mine = owner(mod.rel)
        for constant in mod.constants:
            if words.get(constant, {mine}) - {mine}:
                found[mod.rel].add(repr(constant))
        for target in mod.imports | mod.type_only | mod.strings:
            theirs = owner(mods[target].rel)
            if theirs and theirs != mine and not target.startswith("hilbench.protocols."):
                found[mod.rel].add(f"import {target}")
    new = {rel: sorted(v - NAMES_A_FAMILY.get(rel, set()) - NOT_A_FAMILY.get(rel, set())) for rel, v in found.items()}
    new = {rel: v for rel, v in new.items() if v}
    assert not new, f"shared modules naming a family (let the family contribute it through the registry): {new}"
    gone = {rel: sorted(v - found.get(rel, set())) for rel, v in NAMES_A_FAMILY.items()}
    gone = {rel: v for rel, v in gone.items() if v}
    assert not gone, f"delete from NAMES_A_FAMILY, these names are gone: {gone}"
