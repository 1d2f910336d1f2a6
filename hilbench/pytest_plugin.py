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
    A factory for more benches: ``hilbench_bench("wolfgang", paced=True)``;
    ``hilbench_bench("mecarover-can", virtual_time=True)`` runs one in virtual time (the
    ``Bench`` keywords: ``virtual_epoch``, ``lockstep_stall``, ``seed``), whose clock clients started
    with ``hilbench_run`` share.
``hilbench_emulator``
    A factory that runs ``hilbench emulate`` in a separate process, as a user
    would, and returns its manifest once every endpoint is ready.
``hilbench_world``
    The ``bench`` fixture's world (:class:`~hilbench.bench.world.BenchWorld`): the truth a test compares
    with what its clients measured, ``body("rover").pose``, ``place("r1", x, y, theta)``, ``record(path)``.
    (Any fixture bench has it as ``bench.world``; an emulator answers ``ControlClient.world()``.)
``hilbench_run``
    Clients in other processes with a serial adapter's semantics (``hilbench
    run``) against a fixture bench or an emulator: ``hilbench_run.command(bench,
    "python", "client.py")`` or ``env=hilbench_run.env(bench)``.

Every factory and the marker take ``set={"dxl.baud": 1_000_000, "can.socketcand.port": 0}``: profile keys
changed before the bench starts and checked as the file is, as ``hilbench emulate --set`` does
(:func:`hilbench.bench.profile.apply_overrides`), so a test moves a bench's port, baud or domain without a
copy of the profile.

Benches started by these fixtures (emulators too) serve modem lines, BREAK and
flushes: their port-state server runs, and pyserial in the test's own process talks
to it for their ptys (``ser.dtr = False`` reaches the devices' ``on_port_event``, ``ser.cts`` reads
what they drive, ``reset_output_buffer()`` delivers instead of discarding), as
it would under ``hilbench run``. ``hilbench_bench(profile, port_state=False)`` opts out.

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
from hilbench.bench.manifest import read_manifest
from hilbench.bench.port_state_server import serve_port_state
from hilbench.bench.profile import DEFAULT_PROFILE, load_profile
from hilbench.run import pyserial_shim


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
        "hilbench_profile(name, paced=None, link_dir=None, set=None): profile the `bench` fixture starts "
        "(set: {KEY: VALUE} profile overrides, as hilbench emulate --set)",
    )
    if config.getoption("hilbench_labgrid"):
        _check_labgrid(config)


def _check_labgrid(config: pytest.Config) -> None:
    """``--hilbench-labgrid`` takes the bench from labgrid's ``env`` fixture: without labgrid (or with its
    pytest plugin off) say what is missing once, as a usage error, not "fixture 'env' not found" per test."""
    import importlib.util

    try:  # labgrid's plugin module, not any directory called labgrid on sys.path
        found = importlib.util.find_spec("labgrid.pytestplugin") is not None
    except ImportError:
        found = False
    if not found:
        raise pytest.UsageError("--hilbench-labgrid needs labgrid, which is not installed: "
                                "pip install 'hilbench[labgrid]'")
    if not any(config.pluginmanager.hasplugin(name) for name in ("labgrid", "labgrid.pytestplugin")):
        raise pytest.UsageError("--hilbench-labgrid needs labgrid's pytest plugin (its `env` fixture and "
                                "--lg-env), which is not loaded here (-p no:labgrid?)")


def serve_port_state_in_process(bench: Bench) -> list[int]:
    """Start ``bench``'s port-state server and let pyserial in this process use it for the bench's ptys.

    Returns the ptys' device numbers, for :func:`stop_lines_in_process`.
    """
    server = serve_port_state(bench)
    if server is None:
        return []
    for rdev in server.rdevs:
        pyserial_shim.register(rdev, server.handle, server.ledger.path)
    pyserial_shim.install()
    return server.rdevs


def stop_lines_in_process(rdevs: list[int]) -> None:
    """Undo :func:`serve_port_state_in_process` (pyserial is unpatched once no bench is left)."""
    for rdev in rdevs:
        pyserial_shim.unregister(rdev)
    if not pyserial_shim.PORTS:
        pyserial_shim.uninstall()


@pytest.fixture
def hilbench_bench() -> Iterator[Callable[..., Bench]]:
    """Factory: ``hilbench_bench(profile, paced=None, link_dir=None, port_state=True, set=None)`` starts a bench,
    stopped after the test; ``port_state`` serves its modem lines, BREAK and flushes (see the module's docstring);
    ``set`` changes profile keys first (``{"dxl.baud": 1_000_000}``, as ``hilbench emulate --set``)."""
    benches: list[tuple[Bench, list[int]]] = []

    def start(profile: str | Path = DEFAULT_PROFILE, *, port_state: bool = True, set: dict[str, Any] | None = None,
              **kwargs: Any) -> Bench:
        if set:
            profile = load_profile(profile, set)
        b = Bench(profile, **kwargs).start()
        benches.append((b, serve_port_state_in_process(b) if port_state else []))
        return b

    yield start
    for b, rdevs in benches:
        stop_lines_in_process(rdevs)
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


@pytest.fixture
def hilbench_world(bench: Any) -> Any:
    """The world of the ``bench`` fixture (its bodies, their true poses, placing them, recording them)."""
    return bench.world


def _labgrid_bench(request: pytest.FixtureRequest) -> Any:
    from hilbench.labgrid.remote import bench_from_target

    env = request.getfixturevalue("env")  # labgrid's own fixture (--lg-env); pytest_configure checked it exists
    role = request.config.getoption("hilbench_lg_role")
    target = env.get_target(role)
    if target is None:
        pytest.fail(f"the labgrid environment has no target {role!r}")
    return bench_from_target(target)


@pytest.fixture
def hilbench_emulator() -> Iterator[Callable[..., dict[str, Any]]]:
    """Factory: run ``hilbench emulate PROFILE [ARGS]`` in a subprocess (``set={KEY: VALUE}``: ``--set``
    overrides; ``virtual_time=True`` (or ``"free"``): ``--virtual-time``, clients under ``hilbench_run`` then
    share its clock); returns its manifest.

    The manifest also carries ``"process"`` (the :class:`subprocess.Popen`) and
    ``"manifest_path"`` (the file, for ``hilbench run --manifest``).
    """
    procs: list[subprocess.Popen] = []
    tmp = tempfile.TemporaryDirectory(prefix="hilbench-")

    def start(profile: str | Path = DEFAULT_PROFILE, *args: str, timeout: float = 20.0,
              set: dict[str, Any] | None = None, virtual_time: bool | str = False) -> dict[str, Any]:
        manifest = Path(tmp.name) / f"manifest-{len(procs)}.json"
        overrides = [a for key, value in (set or {}).items() for a in ("--set", f"{key}={_toml_text(value)}")]
        if virtual_time:
            overrides += ["--virtual-time"] + ([] if virtual_time is True else [str(virtual_time)])
        cmd = [sys.executable, "-m", "hilbench.cli", "emulate", str(profile), "--manifest", str(manifest), *overrides,
               *args]
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
        data["manifest_path"] = str(manifest)
        lines = data.get("port_state") or {}
        for port in (lines.get("ports") or {}).values():  # pyserial in this process: as under hilbench run
            pyserial_shim.register(int(port["rdev"]), lines["socket"])
            registered.append(int(port["rdev"]))
        if registered:
            pyserial_shim.install()
        return data

    registered: list[int] = []
    yield start
    stop_lines_in_process(registered)
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


def _toml_text(value: Any) -> str:
    """A Python value as TOML value text for ``--set`` (strings, numbers, booleans and arrays of them)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str | list | tuple):
        return json.dumps(list(value) if isinstance(value, tuple) else value)  # JSON's are TOML's here
    raise TypeError(f"set: {value!r}: give a string, number, boolean or array")


class RunHelper:
    """What the ``hilbench_run`` fixture gives: ``hilbench run`` for clients of a test's benches.

    ``bench`` below is a fixture :class:`Bench`, a manifest from ``hilbench_emulator``,
    or a manifest file.
    """

    def __init__(self, directory: Path) -> None:
        self._dir = directory
        self._written: dict[int, Path] = {}

    def manifest(self, bench: Bench | dict[str, Any] | str | os.PathLike[str]) -> str:
        """The manifest file of ``bench`` (written for an in-process bench, its port-state server started)."""
        if isinstance(bench, Bench):
            serve_port_state(bench)
            path = self._written.get(id(bench)) or self._dir / f"manifest-{len(self._written)}.json"
            bench.write_manifest(path)
            self._written[id(bench)] = path
            return str(path)
        if isinstance(bench, dict):
            return str(bench["manifest_path"])
        return str(bench)

    def command(self, bench: Any, *argv: str, shim: str | None = None) -> list[str]:
        """``[python, -m, hilbench.cli, run, --manifest, FILE, (--shim, S,) --, *argv]``."""
        extra = ["--shim", shim] if shim else []
        return [sys.executable, "-m", "hilbench.cli", "run", "--manifest", self.manifest(bench), *extra, "--",
                *argv]

    def env(self, bench: Any, shim: str = "auto") -> dict[str, str]:
        """``os.environ`` plus what ``hilbench run`` adds (for ``subprocess.Popen(..., env=...)``)."""
        from hilbench.run.environment import read_bench, run_environment

        env, _notes = run_environment([read_bench(self.manifest(bench))], shim)
        return env


@pytest.fixture
def hilbench_run(tmp_path_factory: pytest.TempPathFactory) -> RunHelper:
    """``hilbench run`` for subprocess clients of the test's benches (see :class:`RunHelper`)."""
    return RunHelper(tmp_path_factory.mktemp("hilbench-run"))
