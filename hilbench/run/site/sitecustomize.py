"""Loaded by every Python that ``hilbench run`` starts with its Python fallback (this directory is put
first on PYTHONPATH): pyserial on the bench's ptys gets a serial adapter's modem lines, BREAK and
flushes (see hilbench/run/pyserial_shim.py, loaded from beside this directory by path so that an
interpreter without hilbench installed works too). Then the sitecustomize this one hides, if any,
runs as it would have. Nothing here may stop the program: every failure is silent.
"""

import importlib.machinery
import importlib.util
import os
import sys


def _load_shim() -> None:
    here = os.path.dirname(os.path.abspath(__file__))
    path = os.path.join(os.path.dirname(here), "pyserial_shim.py")
    spec = importlib.util.spec_from_file_location("_hilbench_run_pyserial_shim", path)
    if spec is None or spec.loader is None:
        return
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    if module.load_env():
        module.install()


def _chain() -> None:
    here = os.path.dirname(os.path.abspath(__file__))
    rest = [p for p in sys.path if os.path.abspath(p or os.curdir) != here]
    spec = importlib.machinery.PathFinder.find_spec("sitecustomize", rest)
    if spec is None or spec.loader is None:
        return
    module = importlib.util.module_from_spec(spec)
    sys.modules["sitecustomize"] = module
    spec.loader.exec_module(module)


for _step in (_load_shim, _chain):
    try:
        _step()
    except Exception as _exc:  # a broken hook must not break the user's program
        if os.environ.get("HILBENCH_RUN_DEBUG"):
            print(f"hilbench run: {_step.__name__}: {_exc!r}", file=sys.stderr)
