"""The viewer flags of every command and the Rerun recording they open.

``--rerun`` streams to a viewer: a local one is spawned (or joined when it already runs), or,
with a URL (``--rerun rerun+http://laptop:9876/proxy``), one on another machine: the robot's
own computer has no display. ``--rerun-save FILE.rrd`` writes the recording to a file (open it
later with ``rerun FILE.rrd``). Both may be given. The file is written under a hidden name
beside it and moved into place when the run ends, whatever the way out, so a crash never leaves
a torn ``.rrd`` under the name asked for.

The Rerun SDK is an optional extra: without it the flags exit with status 2 and say how to
install it, before any work.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from core.atomic import move_into_place, temporary_sibling
from core.cli import UsageError, check_output_file

#: how to get the SDK, for the error a missing one gives
INSTALL_HINT = "pip install -e '.[viz]' (the rerun-sdk package)"
APPLICATION_ID = "limo-toponav"
#: ``--rerun`` without a URL: spawn a local viewer (or join the one already running)
SPAWN = "spawn"
#: what a viewer's URL starts with
URL_SCHEMES = ("rerun+http://", "rerun+https://", "rerun://")


class ViewerUnavailableError(UsageError):
    """The viewer was asked for and the Rerun SDK is not installed (exit 2)."""


@dataclass(frozen=True)
class ViewerTarget:
    """Where a run's recording goes: a live viewer (``live``: :data:`SPAWN` or a viewer's URL),
    a file (``save_path``), or both."""

    live: Optional[str] = None
    save_path: Optional[Path] = None

    def __post_init__(self) -> None:
        if self.live is None and self.save_path is None:
            raise ValueError("a viewer target needs a live viewer or a file")


def add_viewer_arguments(parser: argparse.ArgumentParser) -> None:
    """``--rerun [URL]`` and ``--rerun-save FILE.rrd``."""
    group = parser.add_argument_group("viewer (Rerun; pip install -e '.[viz]')")
    group.add_argument("--rerun", nargs="?", const=SPAWN, default=None, metavar="URL",
                       help="stream the run to a Rerun viewer: spawn a local one (or join it), or connect to URL, "
                            "e.g. rerun+http://laptop:9876/proxy")
    group.add_argument("--rerun-save", type=Path, default=None, metavar="FILE.rrd",
                       help="write the run's Rerun recording to this file (open it with: rerun FILE.rrd)")


def viewer_target(args: argparse.Namespace) -> Optional[ViewerTarget]:
    """The target the flags ask for (None: no viewer), checked before any work: the path can be
    written and ends in ``.rrd``, and the SDK is installed."""
    live, save = getattr(args, "rerun", None), getattr(args, "rerun_save", None)
    if live is None and save is None:
        return None
    if live is not None and live != SPAWN and not live.startswith(URL_SCHEMES):
        raise UsageError(f"--rerun {live}: expected a viewer URL such as rerun+http://laptop:9876/proxy")
    if save is not None:
        check_output_file("--rerun-save", save)
        if save.suffix != ".rrd":
            raise UsageError(f"--rerun-save {save}: a Rerun recording's name ends in .rrd")
    rerun_sdk()
    return ViewerTarget(live=live, save_path=save)


def rerun_sdk() -> Any:
    """The ``rerun`` module, or :class:`ViewerUnavailableError` saying how to install it."""
    try:
        import rerun
    except ImportError:
        raise ViewerUnavailableError(f"--rerun / --rerun-save need the Rerun SDK: {INSTALL_HINT}") from None
    return rerun


class Recording:
    """One open recording (a ``rerun.RecordingStream``) with its sinks; :meth:`close` flushes it
    and moves the file into place. Use as a context manager."""

    def __init__(self, target: ViewerTarget, name: str, *, blueprint: Any = None,
                 recording_id: Optional[str] = None):
        rr = rerun_sdk()
        self.rr = rr
        self.target = target
        self.stream = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        self._part: Optional[Path] = None
        sinks = []
        if target.save_path is not None:
            target.save_path.parent.mkdir(parents=True, exist_ok=True)
            self._part = temporary_sibling(target.save_path)
            sinks.append(rr.FileSink(str(self._part)))
        if target.live == SPAWN:
            # starts the viewer when none listens on the local port; the stream then connects to it
            self.stream.spawn(connect=False, default_blueprint=blueprint)
            sinks.append(rr.GrpcSink())
        elif target.live is not None:
            sinks.append(rr.GrpcSink(target.live))
        self.stream.set_sinks(*sinks, default_blueprint=blueprint)
        self.stream.send_recording_name(name)

    def close(self) -> Optional[Path]:
        """Flush the recording; the file (when one is written) is then at its path."""
        if self.stream is None:
            return self.target.save_path
        self.stream.flush()
        self.stream.disconnect()
        self.stream = None
        if self._part is not None and self._part.exists():
            move_into_place(self._part, self.target.save_path)
        return self.target.save_path

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
