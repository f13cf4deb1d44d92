"""The world files: ``configs/worlds/NAME.yaml`` by name, or any path; read and checked.

``load_world("hospital")`` reads ``configs/worlds/hospital.yaml`` with
:func:`core.configfile.load_config`, then :func:`sim.world_checks.check_world` checks what types
alone cannot. Every error is a :class:`sim.world_spec.WorldError` naming the file and the field,
e.g. ``configs/worlds/x.yaml: walls[3].height_m: expected a number, got 'high'``.
"""

from __future__ import annotations

from pathlib import Path

from core.configfile import ConfigError, load_config
from sim.world_checks import check_world
from sim.world_spec import WorldError, WorldSpec

#: repository root: the parent of the ``sim`` package
REPO_ROOT = Path(__file__).resolve().parent.parent
WORLDS_DIR = REPO_ROOT / "configs" / "worlds"


def available_worlds(directory: Path = WORLDS_DIR) -> list[str]:
    """Names of the worlds shipped in ``configs/worlds``."""
    return sorted(p.stem for p in Path(directory).glob("*.yaml"))


def resolve_world_path(name_or_path: str | Path) -> Path:
    """A bare name means ``configs/worlds/NAME.yaml``; anything else is a path."""
    text = str(name_or_path)
    if "/" not in text and "\\" not in text and not text.endswith((".yaml", ".yml")):
        path = WORLDS_DIR / f"{text}.yaml"
        if not path.is_file():
            known = ", ".join(available_worlds()) or "none"
            raise WorldError(str(path), "", f"no world named {text!r} (available: {known})")
        return path
    return Path(name_or_path)


def load_world(name_or_path: str | Path) -> WorldSpec:
    """Read and check a world: a bare name (``hospital``) or a path to a YAML file."""
    path = resolve_world_path(name_or_path)
    try:
        spec = load_config(WorldSpec, path)
    except WorldError:
        raise
    except ConfigError as exc:
        raise WorldError(exc.source, exc.field, exc.problem) from None
    check_world(spec, str(path))
    return spec
