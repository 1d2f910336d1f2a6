"""`hilbench run` tests build the preload shim into a cache of their own, not the user's."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from hilbench.run.build import ShimBuildError, shim_library

CLIENTS = Path(__file__).parent / "clients"


@pytest.fixture(scope="session")
def _shim_cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("xdg-cache")


@pytest.fixture(autouse=True)
def _shim_cache(_shim_cache_dir, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(_shim_cache_dir))


@pytest.fixture(scope="module")
def library() -> Path:
    """The preload library (shim and clock), built once per module; the module is skipped if it cannot be."""
    try:
        return shim_library()
    except ShimBuildError as exc:
        pytest.skip(f"the preload library cannot be built: {exc}")


def build_c_client(tmp_path_factory: pytest.TempPathFactory, name: str) -> str:
    """``clients/NAME.c`` compiled (warnings as errors) into a temporary directory; skips without a compiler."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc or gcc): the C test client cannot be built")
    exe = tmp_path_factory.mktemp(name.replace("_", "-")) / name
    subprocess.run([cc, "-O2", "-Wall", "-Wextra", "-Werror", "-pthread", "-o", str(exe), str(CLIENTS / f"{name}.c")],
                   check=True, capture_output=True)
    return str(exe)
