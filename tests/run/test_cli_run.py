"""`hilbench run` as a command: finding the bench, one-line errors, the child's status and signals, the
compiler fallback."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.port_state_server import serve_port_state
from hilbench.pytest_plugin import wait_until

HILBENCH = [sys.executable, "-m", "hilbench.cli"]


def run(*args: str, env: dict | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([*HILBENCH, *args], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def test_help_names_the_limits():
    proc = run("run", "--help")
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())
    for words in ("statically linked", "setuid", "raw system calls", "glibc", "pyserial", "exec"):
        assert words in text


def test_no_bench_given_is_a_usage_error():
    env = {k: v for k, v in os.environ.items() if k != "HILBENCH_MANIFEST"}
    proc = subprocess.run([*HILBENCH, "run", "--", "true"], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "no bench given: --manifest FILE" in proc.stderr


def test_missing_manifest_and_stopped_bench(tmp_path):
    proc = run("run", "--manifest", str(tmp_path / "none.json"), "--", "true")
    assert proc.returncode == 1 and "none.json: no such manifest (is the bench running?" in proc.stderr
    with Bench("arm") as bench:
        serve_port_state(bench)
        path = str(tmp_path / "arm.json")
        bench.write_manifest(path)  # left behind, as after a crash
    data = json.loads(Path(path).read_text())
    proc = run("run", "--manifest", path, "--", "true")
    assert proc.returncode == 1
    assert f"the bench (pid {data['pid']}) does not answer on {data['port_state']['socket']}" in proc.stderr
    del data["port_state"]  # a bench without ptys (or one that stopped: its pid is gone)
    gone = subprocess.Popen(["true"])
    gone.wait()
    data["pid"] = gone.pid
    (tmp_path / "old.json").write_text(json.dumps(data))
    proc = run("run", "--manifest", str(tmp_path / "old.json"), "--", "true")
    assert proc.returncode == 1 and f"bench not running (stale manifest, pid {data['pid']} gone)" in proc.stderr
    data["pid"] = os.getpid()  # running, no ptys: the command runs unchanged
    (tmp_path / "nolines.json").write_text(json.dumps(data))
    proc = run("run", "--manifest", str(tmp_path / "nolines.json"), "--", "true")
    assert proc.returncode == 0 and "has no pty endpoints; COMMAND runs unchanged" in proc.stderr
    (tmp_path / "junk.json").write_text("{")
    proc = run("run", "--manifest", str(tmp_path / "junk.json"), "--", "true")
    assert proc.returncode == 2 and "not a bench manifest" in proc.stderr


def test_no_command_and_unknown_command(hilbench_bench, hilbench_run):
    path = hilbench_run.manifest(hilbench_bench("arm"))
    proc = run("run", "--manifest", path)
    assert proc.returncode == 2 and "no command to run" in proc.stderr
    proc = run("run", "--manifest", path, "--", "no-such-program-hilbench")
    assert proc.returncode == 127 and "no-such-program-hilbench: command not found" in proc.stderr


def test_exit_status_pid_and_environment_are_the_programs(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arm")
    path = hilbench_run.manifest(bench)
    assert run("run", "--manifest", path, "--", "sh", "-c", "exit 7").returncode == 7
    # The manifest may also come from HILBENCH_MANIFEST; the program replaces hilbench run (same pid).
    code = "import os; print(os.getpid(), os.environ['HILBENCH_RUN_PORTS'])"
    proc = subprocess.Popen([*HILBENCH, "run", "--", sys.executable, "-c", code], stdout=subprocess.PIPE,
                            text=True, env={**os.environ, "HILBENCH_MANIFEST": path})
    out, _ = proc.communicate(timeout=60)
    pid, ports = out.split()
    assert int(pid) == proc.pid
    assert ports == f"{bench.endpoint().port.rdev}={bench.services['port_state'].path}"


def test_signals_reach_the_program(hilbench_bench, hilbench_run):
    path = hilbench_run.manifest(hilbench_bench("arm"))
    code = ("import signal, sys, time\n"
            "signal.signal(signal.SIGTERM, lambda *_: sys.exit(3))\n"
            "print('ready', flush=True)\n"
            "time.sleep(60)\n")
    proc = subprocess.Popen([*HILBENCH, "run", "--manifest", path, "--", sys.executable, "-c", code],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=10) == 3
    proc.stdout.close()


def test_without_a_compiler_python_clients_get_the_fallback(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arm")
    path = hilbench_run.manifest(bench)
    code = "import os, serial, sys; s = serial.Serial(sys.argv[1]); s.rts = False; print(os.environ['HILBENCH_RUN'])"
    proc = run("run", "--manifest", path, "--", sys.executable, "-c", code, bench.endpoint().path,
               env={"CC": "/nonexistent/cc"})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "python"
    assert "hilbench run: note: no C compiler (CC='/nonexistent/cc' not found); pyserial clients get the " \
           "Python fallback" in proc.stderr
    wait_until(lambda: bench.endpoint().port.port_state.rts is False)
    proc = run("run", "--shim", "c", "--manifest", path, "--", "true", env={"CC": "/nonexistent/cc"})
    assert proc.returncode == 1 and "no C compiler" in proc.stderr


def test_verbose_and_shim_from_the_environment(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arm")
    path = hilbench_run.manifest(bench)
    proc = run("run", "-v", "--manifest", path, "--", "true", env={"HILBENCH_RUN_SHIM": "python"})
    assert proc.returncode == 0
    assert f"hilbench run: arm: {bench.endpoint().path}" in proc.stderr
    assert "hilbench run: shim: python" in proc.stderr


@pytest.mark.parametrize("bad", ["fast"])
def test_bad_shim_name(hilbench_bench, hilbench_run, bad):
    path = hilbench_run.manifest(hilbench_bench("arm"))
    proc = run("run", "--manifest", path, "--", "true", env={"HILBENCH_RUN_SHIM": bad})
    assert proc.returncode == 2 and "unknown shim 'fast'; expected one of auto, c, python" in proc.stderr
