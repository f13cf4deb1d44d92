"""Command-line plumbing shared by every command: one-line usage errors, checked numbers and paths.

Every command of the project answers bad input with one line on stderr naming the option, file or
value, and exit status 2, before it starts any work (and before it writes anything). argparse's
own errors print the usage block first; :class:`Parser` prints the one line only (``--help``
shows the usage). Output paths are checked before the work too (:func:`check_output_file`,
:func:`check_output_folder`), so hours of computation are never lost to a path that cannot be
written.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Callable, NoReturn, Optional

EXIT_OK = 0
EXIT_FAILED = 1         # the run itself failed (robot stuck, lost, base not answering)
EXIT_USAGE = 2          # bad arguments, configuration or input files
EXIT_INTERRUPTED = 130  # Ctrl-C; SIGTERM 143, SIGHUP 129 (core.shutdown)


class UsageError(ValueError):
    """Arguments that cannot work; the message names the option or file (exit 2)."""


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line: ``PROG: error: MESSAGE (see --help)``."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def _number(kind: Callable[[str], float], test: Callable[[float], bool], what: str) -> Callable[[str], float]:
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if isinstance(value, float) and not math.isfinite(value) or not test(value):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value
    parse.__name__ = what          # argparse names the type in some messages
    return parse


positive_int = _number(int, lambda v: v >= 1, "an integer >= 1")
non_negative_int = _number(int, lambda v: v >= 0, "an integer >= 0")
positive_float = _number(float, lambda v: v > 0, "a number > 0")
non_negative_float = _number(float, lambda v: v >= 0, "a number >= 0")


def existing_file(option: str, path: Optional[Path], what: str = "file") -> None:
    """``path`` (when given) must be a file; says when it is a folder or missing."""
    if path is None:
        return
    if Path(path).is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a {what}")
    if not Path(path).is_file():
        raise UsageError(f"{option} {path}: no such {what}")


def existing_folder(option: str, path: Optional[Path], what: str = "folder") -> None:
    """``path`` (when given) must be a folder; says when it is a file or missing."""
    if path is None:
        return
    if Path(path).is_file():
        raise UsageError(f"{option} {path}: is a file, expected a {what}")
    if not Path(path).is_dir():
        raise UsageError(f"{option} {path}: no such {what}")


def _writable_parent(option: str, path: Path) -> None:
    for parent in Path(path).absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise UsageError(f"{option} {path}: {parent} is a file, not a folder")
            return


def check_output_file(option: str, path: Optional[Path]) -> None:
    """``path`` (when given) can become a file: it is not a folder and no file stands where one
    of its folders must go."""
    if path is None:
        return
    if Path(path).is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a file name to write")
    _writable_parent(option, Path(path))


def check_output_folder(option: str, path: Optional[Path]) -> None:
    """``path`` (when given) can become a folder: it is not a file and no file stands where one of
    its parent folders must go."""
    if path is None:
        return
    if Path(path).exists() and not Path(path).is_dir():
        raise UsageError(f"{option} {path}: is a file, expected a folder")
    _writable_parent(option, Path(path))


def quiet_video_decoder() -> None:
    """Keep FFmpeg's own messages ("moov atom not found") off stderr, which carries the command's
    one line: OpenCV reads this before it opens its first video (a user's setting wins)."""
    import os

    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
