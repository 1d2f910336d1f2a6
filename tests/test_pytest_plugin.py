"""The pytest plugin as a user meets it: `pytest --hilbench-labgrid` where labgrid is missing."""

from __future__ import annotations

import importlib.util
import subprocess
import sys


def _pytest(tmp_path, *args: str) -> subprocess.CompletedProcess:
    (tmp_path / "test_uses_bench.py").write_text("def test_uses_bench(bench):\n    assert bench\n")
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args,
                           "test_uses_bench.py"], capture_output=True, text=True, timeout=120, cwd=tmp_path)


def test_hilbench_labgrid_without_labgrid_names_the_extra(tmp_path):
    """A usage error (exit 4) naming what to install, not "fixture 'env' not found" in every test."""
    if importlib.util.find_spec("labgrid") is None:
        proc = _pytest(tmp_path, "--hilbench-labgrid")
        expected = "ERROR: --hilbench-labgrid needs labgrid, which is not installed: pip install 'hilbench[labgrid]'"
    else:  # the labgrid venv: its plugin switched off instead
        proc = _pytest(tmp_path, "-p", "no:labgrid", "--hilbench-labgrid")
        expected = "ERROR: --hilbench-labgrid needs labgrid's pytest plugin"
    assert proc.returncode == 4, proc.stdout + proc.stderr
    assert proc.stderr.strip().startswith(expected)
    assert "fixture 'env' not found" not in proc.stdout + proc.stderr
