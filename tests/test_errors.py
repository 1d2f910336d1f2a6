"""One root for errors (hilbench/errors.py): every exception class hilbench defines is a HilbenchError, the
ones callers catch as ValueError still are, and an optional extra that is missing is named in one line."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hilbench.errors import FormatError, HilbenchError, MissingExtra, RequestRefused, UsageError, require

# Runs in a fresh interpreter: importing every module of the package must not leak into the other tests.
WALK = r"""
import ast, builtins, importlib, inspect, json, pkgutil, sys
import hilbench
from hilbench.errors import HilbenchError

names = [m.name for m in pkgutil.walk_packages(hilbench.__path__, "hilbench.") if not m.name.endswith(".__main__")]
failed = {}
pending = names
for _ in range(2):  # a module imported first from inside an import cycle fails alone: try it again after the rest
    failed = {}
    for name in pending:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            failed[name] = exc
    pending = list(failed)

checked, offenders = [], []
for name in names:
    module = sys.modules.get(name)
    if module is None:
        continue
    for obj in vars(module).values():
        if not (inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == name):
            continue
        if issubclass(obj, Warning):  # warnings go through warnings.warn, never raised to a user
            continue
        checked.append(f"{name}.{obj.__qualname__}")
        if not issubclass(obj, HilbenchError):
            offenders.append(f"{name}.{obj.__qualname__}{tuple(b.__name__ for b in obj.__mro__[1:-2])}")

# A module that needs an extra this environment lacks (labgrid) is read instead: its classes whose bases are
# Python's exceptions and no hilbench error stand outside the root.
roots = {n.rsplit(".", 1)[1] for n in checked} | {"HilbenchError"}
builtin_errors = {n for n, v in vars(builtins).items() if inspect.isclass(v) and issubclass(v, BaseException)
                  and not issubclass(v, Warning)}
read = []
for name, exc in failed.items():
    if (exc.name or "").startswith("hilbench"):
        offenders.append(f"{name}: cannot be imported: {exc}")
        continue
    path = importlib.util.find_spec(name).origin
    read.append(name)
    for node in ast.walk(ast.parse(open(path, encoding="utf-8").read())):
        if isinstance(node, ast.ClassDef):
            bases = {ast.unparse(b).rsplit(".", 1)[-1] for b in node.bases}
            if bases & builtin_errors and not bases & roots:
                offenders.append(f"{name}.{node.name}{tuple(sorted(bases))}")
print(json.dumps({"checked": checked, "offenders": offenders, "read": read}))
"""


def test_every_exception_class_is_a_hilbench_error():
    proc = subprocess.run([sys.executable, "-c", WALK], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    found = json.loads(proc.stdout.splitlines()[-1])
    assert found["offenders"] == []
    # The walk saw the package: the classes that once stood outside the root are among those it checked.
    for name in ("hilbench.transports.chunk.CaptureError", "hilbench.protocols.vel2d.Vel2dError",
                 "hilbench.fakes.xrce_agent.entities.EntityError", "hilbench.errors.MissingExtra",
                 "hilbench.transports.listener.BindError"):
        assert name in found["checked"]
    assert len(found["checked"]) >= 30


def test_callers_catching_value_error_still_catch_format_errors():
    from hilbench.fakes.xrce_agent.entities import EntityError
    from hilbench.protocols import vel2d
    from hilbench.transports.chunk import CaptureError

    with pytest.raises(ValueError, match="expected 28 bytes") as exc:
        vel2d.parse(b"\x00" * 27)
    assert isinstance(exc.value, FormatError) and exc.value.exit_code == 2
    assert issubclass(CaptureError, FormatError) and issubclass(CaptureError, ValueError)
    refused = EntityError(0x83, "no such type")
    assert isinstance(refused, RequestRefused) and isinstance(refused, ValueError) and refused.status == 0x83
    assert issubclass(FormatError, UsageError)


def test_require_names_the_extra_to_install(monkeypatch):
    assert require("json", "none") is sys.modules["json"]
    monkeypatch.setitem(sys.modules, "cantools", None)  # as if hilbench[can] were not installed
    with pytest.raises(MissingExtra) as exc:
        require("cantools", "can", "decoding with a DBC")
    assert str(exc.value) == "decoding with a DBC needs cantools: pip install 'hilbench[can]'"
    assert (exc.value.module, exc.value.extra, exc.value.exit_code) == ("cantools", "can", 2)
    assert isinstance(exc.value, HilbenchError)


def test_require_says_what_an_installed_extra_itself_misses(tmp_path, monkeypatch):
    # The extra's module is there but cannot import a dependency of its own: the message names that one too.
    (tmp_path / "acme_plotting.py").write_text("import acme_missing_backend\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(MissingExtra) as exc:
        require("acme_plotting", "plot", "--png")
    assert str(exc.value) == ("--png needs acme_plotting (No module named 'acme_missing_backend'): "
                              "pip install 'hilbench[plot]'")
    assert "acme_plotting" not in sys.modules


def test_a_verb_needing_a_missing_extra_says_so_in_one_line(monkeypatch, capsys):
    from hilbench.cli import main

    monkeypatch.setitem(sys.modules, "canopen", None)
    assert main(["can", "sdo", "virtual:nobody", "--node", "1", "read", "0x1000"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.splitlines() == [
        "hilbench: error: hilbench can sdo needs canopen: pip install 'hilbench[can]'"]
