"""core.atomic: a file or folder appears complete at its path or not at all, and it is the one
place that renames files into place."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from core.atomic import AtomicFile, AtomicFolder, recover_folder, remove_debris, write_json, write_text

ROOT = Path(__file__).resolve().parents[1]


def test_write_json_replaces_the_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "deep" / "r.json"
    write_json(path, {"a": 1})
    write_json(path, {"a": 2})
    assert json.loads(path.read_text()) == {"a": 2}
    assert sorted(p.name for p in path.parent.iterdir()) == ["r.json"]


def test_a_failed_write_keeps_the_previous_file(tmp_path):
    path = write_text(tmp_path / "r.json", "old")
    with pytest.raises(TypeError):
        write_json(path, {"not json": object()})
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]


def test_atomic_file_appears_only_on_commit_and_discard_leaves_nothing(tmp_path):
    path = tmp_path / "log.jsonl"
    f = AtomicFile(path)
    f.write("one\n")
    assert not path.exists()
    f.commit()
    assert path.read_text() == "one\n"
    g = AtomicFile(path)
    g.write("two\n")
    g.discard()
    assert path.read_text() == "one\n" and sorted(p.name for p in tmp_path.iterdir()) == ["log.jsonl"]
    with pytest.raises(ValueError, match="already committed"):
        g.write("three\n")


def test_atomic_folder_is_swapped_in_whole_or_not_at_all(tmp_path):
    target = tmp_path / "rec"
    with AtomicFolder(target) as folder:
        folder.write("a.txt", b"first")
        folder.commit()
    with pytest.raises(RuntimeError):
        with AtomicFolder(target) as folder:
            folder.write("a.txt", b"second")
            (folder.path / "b.txt").write_text("written by another writer")
            raise RuntimeError("interrupted")
    assert (target / "a.txt").read_bytes() == b"first" and not (target / "b.txt").exists()
    with AtomicFolder(target) as folder:
        (folder.mkdir("sub") / "c.txt").write_text("c")
        folder.commit()
    assert sorted(p.name for p in target.rglob("*")) == ["c.txt", "sub"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_a_folder_published_once_keeps_the_first_writers_copy(tmp_path):
    target = tmp_path / "cache" / "m"
    with AtomicFolder(target) as first:
        first.write("a.txt", b"first")
        assert first.commit_unless_present()
    inode = target.stat().st_ino
    with AtomicFolder(target) as second:
        second.write("a.txt", b"second")
        assert not second.commit_unless_present()
    assert target.stat().st_ino == inode and (target / "a.txt").read_bytes() == b"first"
    assert [p.name for p in target.parent.iterdir()] == ["m"]          # the loser left nothing


def test_debris_of_a_dead_writer_is_removed_and_a_set_aside_folder_restored(tmp_path):
    target = tmp_path / "m"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    (tmp_path / f".m.saving-{pid}-abcd").mkdir()
    (tmp_path / f".m.tmp-{pid}-abcd").write_text("half")
    (tmp_path / f".m.saving-{os.getpid()}-live").mkdir()        # a write still in progress stays
    remove_debris(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f".m.saving-{os.getpid()}-live"]
    old = tmp_path / ".m.old-1-ffff"
    old.mkdir()
    (old / "manifest.json").write_text("{}")
    assert recover_folder(target, complete=lambda p: (p / "manifest.json").is_file())
    assert (target / "manifest.json").is_file() and not old.exists()


def test_no_other_module_renames_files_into_place():
    """One helper per mechanism: every atomic write of the project goes through core.atomic."""
    pattern = re.compile(r"os\.(replace|rename)\(|\.rename\(|tempfile\.mkstemp")
    offenders = [f"{p.relative_to(ROOT)}:{n}" for package in ("descriptors", "limo", "sim", "maps", "controllers", "robot")
                 for p in (ROOT / package).rglob("*.py")
                 for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if pattern.search(line)]
    assert not offenders, offenders
