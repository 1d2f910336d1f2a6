"""The entry-point cache (hilbench.entry_points): the registry reads the ``hilbench.*`` entry points from a
small file while nothing was installed, and never a table that what it was read from no longer gives.

Each command runs in its own process with its own cache directory (``XDG_CACHE_HOME``), the same working
directory and ``PYTHONPATH`` every time (one ``sys.path``, so one cache file: a change is caught by the
fingerprint, not by a new file).
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from hilbench import entry_points
from hilbench.entry_points import Entry

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "tests" / "example_family"

#: Prints the device families' names as the registry reads them, and whether importlib.metadata was imported.
NAMES = """
import json, sys
from hilbench import registry
print(json.dumps({"families": sorted(registry.families.names()), "metadata": "importlib.metadata" in sys.modules}))
"""


def run(cache: Path, path: Path) -> dict:
    """The families' names in a fresh process whose cache is ``cache`` and with ``path`` on ``sys.path``."""
    env = {**os.environ, "XDG_CACHE_HOME": str(cache), "PYTHONPATH": str(path)}
    proc = subprocess.run([sys.executable, "-c", NAMES], capture_output=True, text=True, timeout=60, env=env,
                          cwd=path)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    return json.loads(proc.stdout)


def cache_files(cache: Path) -> list[Path]:
    return sorted((cache / "hilbench").glob("entry-points-*.json"))


def add_dist(where: Path, project: str, entry_points_txt: str) -> Path:
    """A distribution's metadata as pip writes it (no code: the names are read without importing it)."""
    dist = where / f"{project}-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project.replace('_', '-')}\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(entry_points_txt)
    return dist


@pytest.fixture
def site(tmp_path) -> Path:
    path = tmp_path / "site"
    path.mkdir()
    return path


def test_a_second_run_reads_the_cache_not_the_metadata(tmp_path, site):
    first = run(tmp_path / "cache", site)
    assert first["metadata"] and "dynamixel" in first["families"]  # read from the metadata, then kept
    assert len(cache_files(tmp_path / "cache")) == 1
    second = run(tmp_path / "cache", site)
    assert second == {**first, "metadata": False}  # the same names, without importlib.metadata


def test_a_package_installed_changed_or_removed_is_seen_by_the_next_run(tmp_path, site):
    cache = tmp_path / "cache"
    assert "acme" not in run(cache, site)["families"]
    assert not run(cache, site)["metadata"]  # (cached)
    dist = add_dist(site, "acme_lab", "[hilbench.families]\nacme = acme_lab:FAMILY\n")
    seen = run(cache, site)
    assert "acme" in seen["families"] and seen["metadata"]
    assert not run(cache, site)["metadata"]
    # an entry point rewritten in place (the file's stamp changes, not the directories')
    (dist / "entry_points.txt").write_text("[hilbench.families]\nacme-two = acme_lab:FAMILY\n")
    changed = run(cache, site)["families"]
    assert "acme-two" in changed and "acme" not in changed
    shutil.rmtree(dist)
    gone = run(cache, site)["families"]
    assert "acme" not in gone and "acme-two" not in gone and "dynamixel" in gone
    assert len(cache_files(cache)) == 1  # one sys.path throughout: the fingerprint caught each change


@pytest.mark.slow  # a real pip install (about 6 s); the test above covers the fingerprint's logic in the normal set
def test_pip_install_and_uninstall_are_seen_by_the_next_command(tmp_path):
    """A real ``pip install`` of the example family into a throwaway virtual environment (on top of this one's
    packages), then ``pip uninstall``: ``hilbench --help`` lists its verb after the one and not after the other."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    (site,) = (venv / "lib").glob("python*/site-packages")
    # this environment's packages (hilbench, pip, setuptools) under the new one's, as its own .pth files say
    (site / "outer.pth").write_text(f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    python = str(venv / "bin" / "python")

    def verbs() -> str:
        proc = subprocess.run([python, "-m", "hilbench.cli", "--help"], capture_output=True, text=True,
                              timeout=60, env=env, cwd=tmp_path)
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr
        return proc.stdout

    def pip(*args: str) -> None:
        proc = subprocess.run([python, "-m", "pip", *args], capture_output=True, text=True, timeout=300, env=env,
                              cwd=tmp_path)
        assert proc.returncode == 0 and "Not uninstalling" not in proc.stderr, proc.stderr

    assert "blink" not in verbs()
    assert "blink" not in verbs()  # (from the cache)
    pip("install", "-q", "--no-deps", "--no-build-isolation", "--no-compile", str(EXAMPLE))
    assert list(site.glob("hilbench_example_family-*.dist-info"))
    assert "blink" in verbs()
    assert "blink" in verbs()
    pip("uninstall", "-q", "-y", "hilbench-example-family")
    assert not list(site.glob("hilbench_example_family-*"))
    assert "blink" not in verbs()
    assert len(cache_files(tmp_path / "cache")) == 1  # one sys.path throughout: the fingerprint caught each change


def test_a_cache_directory_that_cannot_be_written_reads_the_metadata_each_time(tmp_path, site):
    blocked = tmp_path / "not-a-directory"
    blocked.write_text("")  # $XDG_CACHE_HOME/hilbench cannot be made
    for _ in range(2):
        out = run(blocked, site)
        assert out["metadata"] and "dynamixel" in out["families"]
    assert blocked.read_text() == ""


@pytest.mark.parametrize("damage", [
    b"", b"{", b"\xff\xfe not json", b"[]", b"null", b'{"format": 1}', b'{"format": 1, "key": 3, "entries": 7}',
    "rows of the wrong length", "fields that are not text", "a directory in its place"])
def test_a_damaged_cache_file_is_read_again_without_a_traceback(tmp_path, site, damage):
    cache = tmp_path / "cache"
    good = run(cache, site)
    (path,) = cache_files(cache)
    doc = json.loads(path.read_text())
    if damage == "rows of the wrong length":
        doc["entries"] = [row[:3] for row in doc["entries"]]
        path.write_text(json.dumps(doc))
    elif damage == "fields that are not text":
        doc["entries"] = [[*row[:3], None] for row in doc["entries"]]
        path.write_text(json.dumps(doc))
    elif damage == "a directory in its place":
        path.unlink()
        path.mkdir()
    else:
        path.write_bytes(damage)
    assert run(cache, site) == {**good, "metadata": True}  # the metadata read again, the same names
    # the file is written anew and the next run reads it (a directory in its place stays: read each time)
    assert run(cache, site) == {**good, "metadata": damage == "a directory in its place"}


def test_the_cached_table_is_the_metadata_s(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    expected = entry_points.from_metadata()
    assert entry_points.read() == expected  # (written)
    assert entry_points.read() == expected  # (read back)
    assert len(expected) > 50 and {e.dist for e in expected} == {"hilbench"}
    every = importlib.metadata.entry_points()
    groups = sorted(g for g in every.groups if g.startswith("hilbench."))
    assert [(e.group, e.name, e.value) for e in expected] == [
        (ep.group, ep.name, ep.value) for g in groups for ep in every.select(group=g)]


def test_a_finder_that_lists_other_distributions_turns_the_cache_off(tmp_path, monkeypatch):
    class Finder:
        @staticmethod
        def find_spec(*args):
            return None

        @staticmethod
        def find_distributions(*args, **kwargs):
            return iter(())

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(sys, "meta_path", [*sys.meta_path, Finder])
    assert entry_points.read() == entry_points.from_metadata()
    assert not (tmp_path / "hilbench").exists()


@pytest.mark.parametrize("value", ["json", "os.path:join", "collections:OrderedDict.fromkeys",
                                   "os.path : join [extra]"])
def test_an_entry_loads_what_importlib_s_entry_point_loads(value):
    ours = Entry("hilbench.x", "x", value, "somebody").load()
    assert ours == importlib.metadata.EntryPoint("x", value, "hilbench.x").load()


def test_the_cache_keeps_the_last_few_files(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    for n in range(entry_points.KEEP + 3):
        monkeypatch.syspath_prepend(str(tmp_path / f"dir{n}"))  # (a new sys.path: a new file)
        entry_points.read()
    assert len(cache_files(tmp_path)) == entry_points.KEEP
