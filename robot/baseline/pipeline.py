"""From a world and its map to a saved action head, in one call: explore, train, save.

:func:`train_baseline` is what the paper harness and ``python -m robot.bench baseline`` call;
:func:`load_baseline` reads the result back. The caller sets torch's thread count (the
bench command uses one thread by default: the machine is shared).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional, Union

from controllers.config import ActionSpeeds
from maps.store import LoadedMap, load_map
from robot.baseline.exploration import ExplorationConfig, collect_expert_data
from robot.baseline.features import FeatureSettings, ImageFeatures, node_features
from robot.baseline.fit import TrainConfig, train_head
from robot.baseline.head import TrainedHead, load_head, save_head
from sim.config import SimConfig
from sim.world_spec import WorldSpec
from sim.worlds import load_world


class BaselineInputError(ValueError):
    """The world and the map do not belong together; the message names both."""


def check_map_world(loaded_map: LoadedMap, world: WorldSpec) -> None:
    """Refuse a map that says it was built in another world (its summary names the world)."""
    built_in = loaded_map.extra.get("world") if isinstance(loaded_map.extra, dict) else None
    if built_in is not None and built_in != world.name:
        raise BaselineInputError(f"map {loaded_map.path} was built in world {built_in!r}, not {world.name!r}; "
                                 "the expert places map nodes by their true poses in the world it explores")


def build_baseline(world: Union[str, Path, WorldSpec], map_dir: Union[str, Path, LoadedMap], *,
                   exploration: ExplorationConfig = ExplorationConfig(), train: TrainConfig = TrainConfig(),
                   features: FeatureSettings = FeatureSettings(), seed: int = 0,
                   sim_config: SimConfig = SimConfig(), speeds: ActionSpeeds = ActionSpeeds(),
                   progress: bool = True) -> TrainedHead:
    """Collect expert data in ``world`` against the map and train a head; nothing is written.

    ``speeds``: the velocities of LEFT / FORWARD / RIGHT during exploration (use the
    navigation's, so the data shows the motions the policy will cause).
    """
    spec = world if isinstance(world, WorldSpec) else load_world(world)
    loaded = map_dir if isinstance(map_dir, LoadedMap) else load_map(map_dir)
    check_map_world(loaded, spec)
    extractor = ImageFeatures(features)
    started = time.perf_counter()
    data = collect_expert_data(spec, loaded, extractor, config=exploration, seed=seed, sim_config=sim_config,
                               speeds=speeds, progress=progress)
    collect_s = time.perf_counter() - started
    ids = [int(n) for n in loaded.topomap.node_ids.tolist()]
    head = train_head(data, ids, node_features(loaded, extractor, ids), config=train, seed=seed,
                      extra_stats={"world": spec.name, "map": str(loaded.path), "map_nodes": len(ids),
                                   "collect_seconds": collect_s,
                                   "steps_per_drive": exploration.steps_per_episode,
                                   "epsilon": exploration.epsilon})
    head.stats["total_seconds"] = time.perf_counter() - started
    return head


def train_baseline(world: Union[str, Path, WorldSpec], map_dir: Union[str, Path, LoadedMap],
                   out_path: Union[str, Path], *, episodes: int = ExplorationConfig.episodes, seed: int = 0,
                   progress: bool = True, exploration: Optional[ExplorationConfig] = None,
                   train: TrainConfig = TrainConfig(), features: FeatureSettings = FeatureSettings(),
                   sim_config: SimConfig = SimConfig(), speeds: ActionSpeeds = ActionSpeeds()) -> Path:
    """Explore ``world`` (``episodes`` drives, ``seed``), train the head, save it to ``out_path``
    (atomically) and return the path. ``exploration`` overrides every exploration setting
    (then ``episodes`` is ignored). Raises ``maps.graph.MapError`` (bad map folder),
    ``sim.world_spec.WorldError``, :class:`BaselineInputError`,
    :class:`robot.baseline.expert.ExpertError` (map without true poses) and the settings'
    own errors.
    """
    if exploration is None:
        exploration = ExplorationConfig(episodes=episodes)
    head = build_baseline(world, map_dir, exploration=exploration, train=train, features=features, seed=seed,
                          sim_config=sim_config, speeds=speeds, progress=progress)
    return save_head(out_path, head)


def load_baseline(path: Union[str, Path]) -> TrainedHead:
    """The trained head saved at ``path``; :class:`robot.baseline.head.BaselineFileError` names
    the file when it is missing, damaged or not a head."""
    return load_head(path)
