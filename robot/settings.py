"""The stack's configuration: one dataclass per component, read once at the entry point.

``configs/default.yaml`` holds every section; a user file given with ``--config`` is read over
it, so fields the file leaves out keep the values of ``configs/default.yaml`` (the stack's tuned
settings, not only the dataclasses' neutral defaults). Each component's dataclass says why each
field exists; errors name the file and the dotted field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controllers.config import NavigationConfig
from core.configfile import from_mapping, load_config, read_yaml_mapping, without_unknown
from core.hal import VelocityLimits
from core.validate import check_at_least, check_count, check_range
from limo.config import LimoSerialConfig
from maps.config import MappingConfig
from robot.episode.config import EpisodeConfig
from sim.config import SimConfig
from sim.teleop import TeleopConfig

REPO_ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = REPO_ROOT / "configs"
DEFAULT_CONFIG = CONFIG_DIR / "default.yaml"


@dataclass(frozen=True)
class RecordingConfig:
    every_n_ticks: int = 2        # record every Nth control tick: 5 Hz at the 10 Hz control rate, ~8 cm apart at cruise speed
    jpeg_quality: int = 95        # high quality so mapping from a recording sees nearly what the live camera sees
    time_budget_factor: float = 3.0  # give up after this many times the walkthrough's length at cruise speed

    def __post_init__(self) -> None:
        check_count("every_n_ticks", self.every_n_ticks, 1)
        check_count("jpeg_quality", self.jpeg_quality, 10)
        check_range("jpeg_quality", self.jpeg_quality, 10, 100)
        check_at_least("time_budget_factor", self.time_budget_factor, 1.0)


@dataclass(frozen=True)
class DescriptorConfig:
    backend: str = "effnet-vlad"   # place descriptor: see descriptors/factory.py for the names
    settings: dict[str, Any] = field(default_factory=dict)   # backend settings (layer, resolution, clusters, ...)
    fit_max_frames: int = 300      # the VLAD vocabulary is fitted on this many evenly spaced walkthrough frames

    def __post_init__(self) -> None:
        check_count("fit_max_frames", self.fit_max_frames, 10)


@dataclass(frozen=True)
class StackConfig:
    sim: SimConfig = field(default_factory=SimConfig)
    teleop: TeleopConfig = field(default_factory=TeleopConfig)
    recording: RecordingConfig = field(default_factory=RecordingConfig)
    descriptor: DescriptorConfig = field(default_factory=DescriptorConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    navigation: NavigationConfig = field(default_factory=NavigationConfig)
    episode: EpisodeConfig = field(default_factory=EpisodeConfig)
    #: the real base (--hal serial, python -m limo.monitor): port, calibration, limits. The limits
    #: are the navigator's own speeds (forward 0.25 m/s, turns 0.5 rad/s): a first run is slow;
    #: raise them after the first-run checklist (README)
    serial: LimoSerialConfig = field(default_factory=lambda: LimoSerialConfig(
        limits=VelocityLimits(max_v_mps=0.25, max_w_radps=0.5)))


def load_stack_config(path: str | Path | None = None) -> StackConfig:
    """Read the stack configuration: ``configs/default.yaml``, with the file at ``path`` (when
    given) read over it, section by section down to single fields."""
    if path is None:
        return load_config(StackConfig, DEFAULT_CONFIG)
    return from_mapping(StackConfig, _merged(read_yaml_mapping(DEFAULT_CONFIG), read_yaml_mapping(path)),
                        source=str(path))


def load_run_record(path: str | Path) -> tuple[StackConfig, list[str]]:
    """A run's record of the configuration its episodes ran with (``config.yaml`` in a run
    folder), read as :func:`load_stack_config` reads a file, less the fields the code no longer
    has (an addition removed since the run): those come back by dotted name, for a note."""
    record, dropped = without_unknown(StackConfig, read_yaml_mapping(path))
    return from_mapping(StackConfig, _merged(read_yaml_mapping(DEFAULT_CONFIG), record), source=str(path)), dropped


def _merged(base: dict, over: dict) -> dict:
    """``over`` read over ``base``: mappings merge key by key, anything else replaces."""
    out = dict(base)
    for key, value in over.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out
