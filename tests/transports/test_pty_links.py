"""Stable links to ptys (``--link-dir``, a profile's ``link``, ``tap --link``) never replace or remove what
hilbench did not make."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from hilbench.transports.pty import LinkRefused, PtyPort, left_by_a_gone_pty


def test_a_link_is_made_and_removed(tmp_path):
    link = tmp_path / "dev" / "arm"
    with PtyPort("arm", link=link) as ep:
        assert os.readlink(link) == ep.path and ep.client_path == str(link)
    assert not os.path.lexists(link)


@pytest.mark.parametrize("kind", ["file", "directory", "symlink", "dangling symlink"])
def test_anything_at_the_links_name_is_refused_and_kept(tmp_path, kind):
    link = tmp_path / "arm"
    if kind == "file":
        link.write_text("the user's notes")
    elif kind == "directory":
        link.mkdir()
    elif kind == "symlink":
        link.symlink_to("/dev/null")
    else:
        link.symlink_to(tmp_path / "gone")  # dangling, but no pty's: maybe the user's, so kept
    before = sorted(os.listdir(tmp_path))
    with pytest.raises(LinkRefused, match=f"^{link}: a .* is there; refusing to replace it"):
        PtyPort("arm", link=link)
    assert sorted(os.listdir(tmp_path)) == before
    if kind == "file":
        assert link.read_text() == "the user's notes"
    elif kind == "symlink":
        assert os.readlink(link) == "/dev/null"


def test_a_link_to_a_live_pty_is_refused(tmp_path):
    with PtyPort("other") as other:
        (tmp_path / "arm").symlink_to(other.path)  # another bench's link (or a reused pty number)
        assert not left_by_a_gone_pty(tmp_path / "arm")
        with pytest.raises(LinkRefused, match=f"a symlink to {other.path} is there"):
            PtyPort("arm", link=tmp_path / "arm")
        assert os.readlink(tmp_path / "arm") == other.path


@pytest.mark.parametrize("target", ["the pty it had", "/dev/pts/99999"])
def test_a_dead_link_a_killed_bench_left_is_replaced(tmp_path, target):
    if target == "the pty it had":
        with PtyPort("old") as old:
            target = old.path  # gone with its bench (and likely the number the next pty gets)
    link = tmp_path / "arm"
    link.symlink_to(target)
    if target == "/dev/pts/99999":
        assert left_by_a_gone_pty(link)
    with PtyPort("arm", link=link) as ep:
        assert os.readlink(link) == ep.path
    assert not os.path.lexists(link)


def test_close_leaves_a_link_someone_else_put_there(tmp_path):
    link = tmp_path / "arm"
    ep = PtyPort("arm", link=link)
    os.unlink(link)
    link.symlink_to("/dev/null")  # the user's own, made while the bench ran
    ep.close()
    assert os.readlink(link) == "/dev/null"
    os.unlink(link)
    ep = PtyPort("arm", link=link)
    os.unlink(link)
    link.write_text("a file now")
    ep.close()
    assert link.read_text() == "a file now"


def test_emulate_refuses_a_taken_link_name_in_one_line(tmp_path):
    (tmp_path / "dev").mkdir()
    (tmp_path / "dev" / "arm").write_text("the user's file")
    proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "emulate", "arm", "--link-dir", str(tmp_path / "dev"),
                           "--manifest", str(tmp_path / "m.json")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr == (f"hilbench: error: {tmp_path / 'dev' / 'arm'}: a file is there; refusing to replace it "
                           "(remove it, or choose another link path or --link-dir)\n")
    assert (tmp_path / "dev" / "arm").read_text() == "the user's file"
    assert sorted(os.listdir(tmp_path)) == ["dev"] and os.listdir(tmp_path / "dev") == ["arm"]
