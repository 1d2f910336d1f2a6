"""`hilbench run` tests build the preload shim into a cache of their own, not the user's."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def _shim_cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("xdg-cache")


@pytest.fixture(autouse=True)
def _shim_cache(_shim_cache_dir, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(_shim_cache_dir))
