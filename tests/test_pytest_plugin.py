"""The pytest plugin as a user meets it: `pytest --hilbench-labgrid` where labgrid is missing."""

from __future__ import annotations

import subprocess
import sys


def _pytest(tmp_path, *args: str) -> subprocess.CompletedProcess:
    (tmp_path / "test_uses_bench.py").write_text("def test_uses_bench(bench):\n    assert bench\n")
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args,
                           "test_uses_bench.py"], capture_output=True, text=True, timeout=120, cwd=tmp_path)


def _labgrid_installed() -> bool:
    """Asked of a fresh interpreter: in this one, a test directory called labgrid may be on sys.path."""
    probe = "import importlib.util as u, sys; sys.exit(0 if u.find_spec('labgrid') else 1)"
    return subprocess.run([sys.executable, "-c", probe], cwd="/", timeout=60).returncode == 0


def test_hilbench_labgrid_without_labgrid_names_the_extra(tmp_path):
    """A usage error (exit 4) naming what to install, not "fixture 'env' not found" in every test."""
    if not _labgrid_installed():
        proc = _pytest(tmp_path, "--hilbench-labgrid")
        expected = "ERROR: --hilbench-labgrid needs labgrid, which is not installed: pip install 'hilbench[labgrid]'"
    else:  # the labgrid venv: its plugin switched off instead
        proc = _pytest(tmp_path, "-p", "no:labgrid", "--hilbench-labgrid")
        expected = "ERROR: --hilbench-labgrid needs labgrid's pytest plugin"
    assert proc.returncode == 4, proc.stdout + proc.stderr
    assert proc.stderr.strip().startswith(expected)
    assert "fixture 'env' not found" not in proc.stdout + proc.stderr
