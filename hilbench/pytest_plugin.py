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

Remote benches: ``pytest --lg-env ENV.yaml --hilbench-labgrid`` takes ``bench``
from the labgrid target of that environment (a ``RemotePlace`` acquired
through a coordinator, or a file from ``hilbench labgrid env``) instead of
starting one (:mod:`hilbench.labgrid.remote`): the same test runs unchanged,
``bench.endpoint().path`` being a local pty bridged to the remote RFC 2217
port. A test whose ``hilbench_profile`` marker names another bench is skipped.
"""

from __future__ import annotations

import json
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


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("hilbench")
    group.addoption("--hilbench-labgrid", action="store_true", default=False,
                    help="take the `bench` fixture from the labgrid target of --lg-env (a RemotePlace or a "
                         "`hilbench labgrid env` file) instead of starting a bench here")
    group.addoption("--hilbench-lg-role", default="main", metavar="TARGET",
                    help="the labgrid target holding the bench (default: main)")


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
def bench(request: pytest.FixtureRequest, hilbench_bench: Callable[..., Bench]) -> Iterator[Any]:
    """A bench from the test's ``hilbench_profile`` marker (default profile otherwise), or with
    ``--hilbench-labgrid`` the bench of the labgrid target."""
    marker = request.node.get_closest_marker("hilbench_profile")
    profile = (marker.args[0] if marker and marker.args else DEFAULT_PROFILE)
    if request.config.getoption("hilbench_labgrid"):
        remote = _labgrid_bench(request)
        wanted = Path(str(profile)).stem
        if marker is not None and wanted != remote.profile.name:
            remote.stop()
            pytest.skip(f"test wants bench {wanted!r}; the labgrid target has {remote.profile.name!r}")
        yield remote
        remote.stop()
        return
    yield hilbench_bench(profile, **(marker.kwargs if marker else {}))


def _labgrid_bench(request: pytest.FixtureRequest) -> Any:
    try:
        from hilbench.labgrid.remote import bench_from_target
    except ImportError as exc:
        pytest.fail(f"--hilbench-labgrid needs labgrid (pip install 'hilbench[labgrid]'): {exc}")
    env = request.getfixturevalue("env")  # labgrid's own fixture (--lg-env)
    role = request.config.getoption("hilbench_lg_role")
    target = env.get_target(role)
    if target is None:
        pytest.fail(f"the labgrid environment has no target {role!r}")
    return bench_from_target(target)


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
        data = json.loads(manifest.read_text())
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
