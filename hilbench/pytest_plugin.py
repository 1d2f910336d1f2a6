"""pytest plugin (registered through the ``pytest11`` entry point): benches as fixtures.

Fixtures
--------
``bench``
    A :class:`~hilbench.bench.Bench` started in this process from the profile
    named by the test's ``@pytest.mark.hilbench_profile("arm", paced=True)``
    marker (default: the bundled default profile). ``bench.endpoint().path`` is
    the pty to open; ``bench.device(3)`` is the emulated device with ID 3, whose
    fault knobs the test may turn.
``hilbench_bench``
    A factory for more benches: ``hilbench_bench("wolfgang", paced=True)``.
``hilbench_emulator``
    A factory that runs ``hilbench emulate`` in a separate process, as a user
    would, and returns its manifest once every endpoint is ready.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from hilbench.bench import Bench
from hilbench.bench.manifest import read_manifest
from hilbench.bench.profile import DEFAULT_PROFILE


def wait_until(predicate: Callable[[], Any], timeout: float = 5.0, interval: float = 0.005) -> Any:
    """Poll ``predicate`` until it returns something truthy; fail the test after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"condition not met within {timeout} s")
        time.sleep(interval)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "hilbench_profile(name, paced=None, link_dir=None): profile the `bench` fixture starts",
    )


@pytest.fixture
def hilbench_bench() -> Iterator[Callable[..., Bench]]:
    """Factory: ``hilbench_bench(profile, paced=None, link_dir=None)`` starts a bench, stopped after the test."""
    benches: list[Bench] = []

    def start(profile: str | Path = DEFAULT_PROFILE, **kwargs: Any) -> Bench:
        b = Bench(profile, **kwargs).start()
        benches.append(b)
        return b

    yield start
    for b in benches:
        b.stop()


@pytest.fixture
def bench(request: pytest.FixtureRequest, hilbench_bench: Callable[..., Bench]) -> Bench:
    """A bench from the test's ``hilbench_profile`` marker (default profile otherwise)."""
    marker = request.node.get_closest_marker("hilbench_profile")
    if marker is None:
        return hilbench_bench(DEFAULT_PROFILE)
    profile = marker.args[0] if marker.args else DEFAULT_PROFILE
    return hilbench_bench(profile, **marker.kwargs)


@pytest.fixture
def hilbench_emulator() -> Iterator[Callable[..., dict[str, Any]]]:
    """Factory: run ``hilbench emulate PROFILE [ARGS]`` in a subprocess; returns its manifest.

    The manifest also carries ``"process"``: the :class:`subprocess.Popen`.
    """
    procs: list[subprocess.Popen] = []
    tmp = tempfile.TemporaryDirectory(prefix="hilbench-")

    def start(profile: str | Path = DEFAULT_PROFILE, *args: str, timeout: float = 20.0) -> dict[str, Any]:
        manifest = Path(tmp.name) / f"manifest-{len(procs)}.json"
        cmd = [sys.executable, "-m", "hilbench.cli", "emulate", str(profile), "--manifest", str(manifest), *args]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        procs.append(proc)
        deadline = time.monotonic() + timeout
        while not manifest.exists():
            if proc.poll() is not None:
                raise RuntimeError(f"hilbench emulate exited with {proc.returncode}: {proc.stderr.read().strip()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"hilbench emulate wrote no manifest within {timeout} s")
            time.sleep(0.01)
        data = read_manifest(manifest)
        data["process"] = proc
        return data

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for stream in (proc.stdout, proc.stderr):
            if stream:
                stream.close()
    tmp.cleanup()
