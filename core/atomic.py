"""Atomic writes: a file or a folder appears complete at its path, or not at all.

Every writer of the project goes through here, so there is one standard: the content is written
next to the target under a hidden temporary name, flushed and fsynced (files and folders), then
renamed into place in one step, and the folder holding it is fsynced. A crash or Ctrl-C at any
point leaves either the previous content or the new one at the target, and at most a hidden
temporary entry beside it that the next write of the same target removes.

* :func:`write_bytes` / :func:`write_text` / :func:`write_json`: one file at once;
* :class:`AtomicFile`: a file written piece by piece (a step log), committed by ``commit()``;
* :class:`AtomicFolder`: a folder written file by file, swapped into place by ``commit()``
  (Linux ``renameat2(RENAME_EXCHANGE)``; elsewhere the previous folder is renamed aside first, and
  :func:`recover_folder` puts it back after a crash between the two renames).
"""

from __future__ import annotations

import ctypes
import errno
import io
import json
import os
import secrets
import shutil
import sys
from pathlib import Path
from typing import IO, Any, Callable, Optional


def _no_checkpoint(step: str) -> None:
    """The default fault-injection hook: does nothing (tests pass one that raises or exits)."""


def fsync_dir(path: str | Path) -> None:
    """Make a folder's entries (new, renamed or removed names) durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_synced(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` (not atomic by itself) and fsync it."""
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _temporary_name(path: Path, kind: str) -> Path:
    return path.with_name(f".{path.name}.{kind}-{os.getpid()}-{secrets.token_hex(4)}")


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (parent folders are created); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temporary_name(path, "tmp")
    try:
        write_synced(tmp, data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, data: Any, indent: Optional[int] = 2) -> Path:
    """Write ``data`` as JSON (with a final newline) to ``path`` atomically."""
    return write_text(path, json.dumps(data, indent=indent) + "\n")


def temporary_sibling(path: str | Path) -> Path:
    """A hidden temporary name beside ``path`` with the same suffix, for writers that need a
    file name of their own (a video encoder); finish with :func:`move_into_place`."""
    path = Path(path)
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}-{secrets.token_hex(4)}{path.suffix}")


def move_into_place(tmp: str | Path, path: str | Path) -> Path:
    """fsync ``tmp`` and rename it to ``path`` in one step."""
    with open(tmp, "rb+") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    fsync_dir(Path(path).parent)
    return Path(path)


def save_figure(fig: Any, path: str | Path, **savefig_kwargs: Any) -> Path:
    """A matplotlib figure saved as PNG atomically (rendered in memory, then :func:`write_bytes`)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", **savefig_kwargs)
    return write_bytes(path, buf.getvalue())


class AtomicFile:
    """A file written piece by piece (text, or bytes with ``binary``) and moved into place by
    :meth:`commit` (or by leaving the ``with`` block, whatever the way out: the pieces written so
    far are kept, never a torn last line). :meth:`discard` drops it instead."""

    def __init__(self, path: str | Path, binary: bool = False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = _temporary_name(self.path, "tmp")
        self._file: Optional[IO] = self._tmp.open("wb") if binary else self._tmp.open("w", encoding="utf-8")

    def write(self, text) -> None:
        if self._file is None:
            raise ValueError(f"{self.path}: already committed or discarded")
        self._file.write(text)

    def commit(self) -> Path:
        if self._file is not None:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            self._file = None
            os.replace(self._tmp, self.path)
            fsync_dir(self.path.parent)
        return self.path

    def discard(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> "AtomicFile":
        return self

    def __exit__(self, *exc) -> None:
        self.commit()


def exchange_paths(a: Path, b: Path) -> bool:
    """Atomically swap two paths (Linux renameat2 with RENAME_EXCHANGE). False where unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(str(a)), at_fdcwd, os.fsencode(str(b)), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def recover_folder(path: str | Path, complete: Callable[[Path], bool] = lambda p: True) -> bool:
    """If a folder write crashed after moving the previous folder aside (the fallback without
    ``RENAME_EXCHANGE``), move the newest complete one back. Returns True when something was
    restored. ``complete(folder)`` says whether a set-aside folder is worth restoring."""
    path = Path(path)
    if path.exists() or path.is_symlink() or not path.parent.is_dir():
        return False
    backups = [p for p in path.parent.glob(f".{path.name}.old-*") if complete(p)]
    if not backups:
        return False
    newest = max(backups, key=lambda p: p.stat().st_mtime)
    os.rename(newest, path)
    fsync_dir(path.parent)
    return True


def remove_debris(path: str | Path) -> None:
    """Remove hidden entries left beside ``path`` by writes that crashed (their process is gone),
    and previous folders set aside once ``path`` exists again."""
    path = Path(path)
    for kind in ("saving", "tmp"):
        for p in path.parent.glob(f".{path.name}.{kind}-*"):
            pid = p.name.rsplit(f".{kind}-", 1)[1].split("-", 1)[0]
            if pid.isdigit() and not _pid_alive(int(pid)):
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
    if path.is_dir():
        for p in path.parent.glob(f".{path.name}.old-*"):
            shutil.rmtree(p, ignore_errors=True)


class AtomicFolder:
    """A folder written file by file in a hidden sibling and swapped into place by :meth:`commit`.

    ``path`` (the temporary folder) takes files while writing: :meth:`write` (fsynced at once) or
    any other writer (fsynced at commit). Leaving a ``with`` block without :meth:`commit` (an
    exception, Ctrl-C) removes the temporary folder; the target is untouched. ``checkpoint(step)``
    is called after every step, for tests that simulate a crash there.
    """

    def __init__(self, target: str | Path, checkpoint: Callable[[str], None] = _no_checkpoint):
        self.target = Path(target)
        self.checkpoint = checkpoint
        self.target.parent.mkdir(parents=True, exist_ok=True)
        remove_debris(self.target)
        self.path = _temporary_name(self.target, "saving")
        os.mkdir(self.path)
        self._synced: set[Path] = set()
        try:
            self.checkpoint("mkdir")
        except BaseException:
            self.discard()
            raise

    def mkdir(self, relpath: str) -> Path:
        folder = self.path / relpath
        folder.mkdir(parents=True, exist_ok=True)
        return folder

    def write(self, relpath: str, data: bytes) -> Path:
        """Write one file (fsynced) into the folder."""
        p = self.path / relpath
        write_synced(p, data)
        self._synced.add(p)
        self.checkpoint(f"write {relpath}")
        return p

    def commit(self) -> Path:
        """fsync everything, then make the folder the target in one step; returns the target."""
        self._fsync()
        self._swap_into_place()
        return self.target

    def commit_unless_present(self) -> bool:
        """Like :meth:`commit`, but a target that exists already (another writer of the same
        content got there first, and may be reading it) stays: this folder is dropped. True when
        this folder became the target."""
        self._fsync()
        try:
            os.rename(self.path, self.target)       # refuses a non-empty folder at the target
        except OSError:
            if not self.target.exists():
                raise
            self.discard()
            return False
        fsync_dir(self.target.parent)
        self.checkpoint("rename into place")
        return True

    def _fsync(self) -> None:
        for folder, _, files in os.walk(self.path, topdown=False):
            for name in files:
                p = Path(folder) / name
                if p not in self._synced:
                    with open(p, "rb+") as fh:
                        os.fsync(fh.fileno())
            fsync_dir(folder)
        self.checkpoint("fsync")

    def discard(self) -> None:
        """Remove the temporary folder (after an exchange it holds the previous folder)."""
        if self.path.exists():
            shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self) -> "AtomicFolder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.discard()

    def _swap_into_place(self) -> None:
        """Once the new folder is at the target the write is committed; removing the previous
        folder is best effort (a leftover is removed by the next write)."""
        tmp, path, checkpoint = self.path, self.target, self.checkpoint
        if not path.exists():
            os.rename(tmp, path)
            fsync_dir(path.parent)
            checkpoint("rename into place")
            return
        if exchange_paths(tmp, path):                   # the commit point
            fsync_dir(path.parent)
            checkpoint("exchange")
            shutil.rmtree(tmp, ignore_errors=True)      # tmp now holds the previous folder
            checkpoint("remove previous")
            return
        old = _temporary_name(path, "old")
        os.rename(path, old)
        try:
            checkpoint("move previous aside")
            os.rename(tmp, path)                        # the commit point
        except BaseException:
            if not path.exists():                       # put the previous folder back at once
                os.rename(old, path)
            raise
        fsync_dir(path.parent)
        checkpoint("rename into place")
        shutil.rmtree(old, ignore_errors=True)
        checkpoint("remove previous")
