"""Cross-references in hilbench's docstrings resolved the way Python resolves the names.

A docstring writes ``:class:`Bench``` in a module that imported ``Bench``, ``:meth:`feed``` in a class
that inherits ``feed``, ``:class:`hilbench.bench.Bench``` (the public import path of a class defined in
``hilbench.bench.bench``) or ``:mod:`tracker``` in the package holding ``tracker.py``; a signature
annotates with a name imported under ``TYPE_CHECKING``. Sphinx looks each of these up by its text only:
it finds nothing (a warning under ``-n``), or, for annotations, it searches every object whose name ends
the same way and may pick a wrong one. Before the references are resolved, this extension follows each
name from where it is written (the class, the module, its ``TYPE_CHECKING`` imports, the package, an
absolute import path) to the object, and rewrites the reference to the object's documented (canonical)
name. A name that leads to nothing documented is left as it was, so it still fails the build; one that
leads to a private object (``_run``, a private base class) is shown as text, as the reference has no
private members.

Builtins (``int``, ``bytes``, ``None``...) are left unlinked: there is no intersphinx, and Sphinx's search
for them otherwise falls back to any hilbench attribute of that name (``bytes`` matched two properties).
"""

from __future__ import annotations

import ast
import builtins
import importlib
import inspect
import sys
import types
from functools import cache
from typing import Any

from docutils import nodes
from sphinx.addnodes import pending_xref
from sphinx.application import Sphinx
from sphinx.transforms.post_transforms import SphinxPostTransform

BUILTINS = frozenset(dir(builtins))
PRIVATE = "<private>"
_MISSING = object()


def _import(name: str) -> types.ModuleType | None:
    if any(part.startswith("__") for part in name.split(".")):
        return sys.modules.get(name)  # never run a __main__ (hilbench.cli.__main__ runs the command)
    try:
        return importlib.import_module(name)
    except Exception:  # noqa: BLE001 (any failure: the name is not a module)
        return None


@cache
def _imported_names(modname: str) -> dict[str, str]:
    """Names a module imports (``from X import Y``, under ``if TYPE_CHECKING:`` too): each to its absolute
    dotted name, so a constant re-exported by value is still found where it is documented."""
    module = sys.modules.get(modname)
    try:
        tree = ast.parse(inspect.getsource(module)) if module is not None else None
    except (OSError, TypeError, SyntaxError):
        tree = None
    if tree is None:
        return {}
    package = modname if hasattr(module, "__path__") else modname.rpartition(".")[0]
    names: dict[str, str] = {}
    for stmt in ast.walk(tree):
        if isinstance(stmt, ast.ImportFrom):
            base = stmt.module or ""
            if stmt.level:
                parent = package.rsplit(".", stmt.level - 1)[0] if stmt.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            for alias in stmt.names:
                names.setdefault(alias.asname or alias.name, f"{base}.{alias.name}")
        elif isinstance(stmt, ast.Import):
            for alias in stmt.names:
                bound = alias.asname or alias.name.split(".")[0]
                names.setdefault(bound, alias.name if alias.asname else bound)
    return names


def _own_name(obj: Any) -> str | None:
    """The dotted name a class, function or module is documented under, if it has one."""
    if isinstance(obj, types.ModuleType):
        return obj.__name__
    if isinstance(obj, (classmethod, staticmethod)):
        obj = obj.__func__
    if isinstance(obj, property):
        obj = obj.fget
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if isinstance(module, str) and isinstance(qualname, str) and "<locals>" not in qualname:
        return f"{module}.{qualname}"
    return None


class _Resolver:
    def __init__(self, objects: dict[str, Any]) -> None:
        self.objects = objects
        self.depth = 0  # nesting of absolute(): import chains are short, a cycle must not recurse forever

    def member(self, owner: Any, owner_name: str, part: str) -> tuple[Any, str | None]:
        """``owner.part``: the object (or _MISSING) and its documented name (or None)."""
        if isinstance(owner, types.ModuleType):
            imported = _imported_names(owner.__name__).get(part)
            if imported == f"{owner.__name__}.{part}":
                imported = None
            if part in vars(owner):
                obj = vars(owner)[part]
                name = _own_name(obj)
                if name is None or name not in self.objects:
                    local = f"{owner_name}.{part}"
                    if local in self.objects:
                        name = local
                    elif imported is not None and self.depth < 8:
                        return self.absolute(imported)
                    else:
                        name = name or local
                return obj, name
            sub = _import(f"{owner.__name__}.{part}") if hasattr(owner, "__path__") else None
            if sub is not None:
                return sub, sub.__name__
            if imported is not None and self.depth < 8:  # e.g. a name imported under TYPE_CHECKING
                return self.absolute(imported)
            return _MISSING, None
        if isinstance(owner, type):
            for base in owner.__mro__:
                base_name = _own_name(base)
                if part in vars(base):
                    obj = vars(base)[part]
                    own = _own_name(obj) if not isinstance(obj, type) or part == obj.__name__ else None
                    return obj, own if own in self.objects else f"{base_name}.{part}"
                if part in getattr(base, "__annotations__", {}) or f"{base_name}.{part}" in self.objects:
                    return _MISSING, f"{base_name}.{part}"  # an instance attribute, documented on the class
        return _MISSING, None

    def walk(self, obj: Any, name: str, parts: list[str]) -> tuple[Any, str | None]:
        """Follow ``parts`` from ``obj`` (documented as ``name``): the object reached and its name."""
        for part in parts:
            if obj is _MISSING:
                return _MISSING, None
            obj, name = self.member(obj, name, part)
            if name is None:
                return _MISSING, None
        return obj, name

    def absolute(self, target: str) -> tuple[Any, str | None]:
        """An absolute dotted name: the longest importable module prefix, then attributes."""
        parts = target.split(".")
        if parts[0] != "hilbench":
            return _MISSING, None
        self.depth += 1
        try:
            for i in range(len(parts), 0, -1):
                module = _import(".".join(parts[:i]))
                if module is not None:
                    return self.walk(module, module.__name__, parts[i:])
            return _MISSING, None
        finally:
            self.depth -= 1

    def canonical(self, target: str, typ: str, modname: str | None, clsname: str | None) -> str | None:
        parts = target.split(".")
        module = _import(modname) if modname else None
        candidates: list[str | None] = []
        if module is not None and clsname:
            cls_obj, cls_name = module, modname
            for part in clsname.split("."):
                cls_obj, cls_name = self.member(cls_obj, cls_name, part)
            if cls_obj is not _MISSING and cls_name:
                candidates.append(self.walk(cls_obj, cls_name, parts)[1])
        if module is not None:
            candidates.append(self.walk(module, modname, parts)[1])
            if typ == "mod" or len(parts) > 1:
                # a sibling module (``:mod:`tracker``` in monitor/dynamixel/summary.py), or a name in it
                package = modname if hasattr(module, "__path__") else modname.rpartition(".")[0]
                parent = _import(package) if package else None
                if parent is not None:
                    candidates.append(self.walk(parent, package, parts)[1])
        candidates.append(self.absolute(target)[1])
        for name in candidates:
            if name and name in self.objects:
                return name
        if any(name and any(part.startswith("_") for part in name.split(".")) for name in candidates):
            return PRIVATE  # exists, but private: not in the reference
        return None


class ResolvePythonNames(SphinxPostTransform):
    """Rewrite hilbench references to documented names before Sphinx resolves them (see the module)."""

    default_priority = 5  # the references are resolved at 10

    def run(self, **kwargs: Any) -> None:
        domain = self.env.domains["py"]
        resolver = _Resolver(domain.objects)
        for node in list(self.document.findall(pending_xref)):
            if node.get("refdomain") != "py":
                continue
            target, typ = node.get("reftarget", ""), node.get("reftype")
            if target in domain.objects:
                continue
            if target in BUILTINS and typ in ("class", "obj", "exc", "data", "func"):
                node.replace_self(node.children[0] if node.children else nodes.literal(text=target))
                continue
            name = resolver.canonical(target, typ, node.get("py:module"), node.get("py:class"))
            if name == PRIVATE:  # a private base class, a private method a docstring explains: plain text
                node.replace_self(node.children[0] if node.children else nodes.literal(text=target))
            elif name is not None:
                node["reftarget"] = name
                if "refspecific" in node:
                    del node["refspecific"]  # an exact name now: no search by suffix


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_post_transform(ResolvePythonNames)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
