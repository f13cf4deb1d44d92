"""Turn a sequence of frames into a saved topological map with its pictures and summary.

One pipeline for every source (a simulated drive, a video, an image folder): read the frames,
fit the descriptor's vocabulary on the walkthrough's own frames (the map-specific vocabulary the
AnyLoc authors support), describe every frame, build the graph (calibrated or explicit
thresholds), save the map folder atomically, then draw the map and the similarity pictures.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Optional, Sequence

import numpy as np
from tqdm import tqdm

from descriptors.base import Descriptor, has_columns
from maps.calibration import similarity_sample
from maps.config import MappingConfig
from maps.pictures import draw_map_picture, draw_similarity_picture
from maps.pipeline import build_map
from maps.store import map_size, save_map
from robot.mapping.sources import FrameSourceError, MapFrame
from robot.viewer.mapping import log_map_build
from robot.viewer.scene import mapping_blueprint
from robot.viewer.stream import Recording, ViewerTarget, rerun_sdk

MAP_PICTURE = "map.png"
SIMILARITY_PICTURE = "similarity.png"


@dataclass(frozen=True)
class MapBuildResult:
    map_dir: Path
    summary: dict


@dataclass(frozen=True)
class WorldPicture:
    """A top-down picture of the world and its world->pixel transform (simulator maps only)."""

    rgb: np.ndarray
    to_pixel: Callable[[float, float], tuple[int, int]]


def describe_frames(descriptor: Descriptor, images: Sequence[np.ndarray], batch_size: int = 16,
                    progress: bool = True, desc: str = "describing") -> np.ndarray:
    """(N, D) float32 descriptors of ``images``, in batches, with a progress bar."""
    rows = []
    with tqdm(total=len(images), unit="frame", desc=desc, disable=not progress) as bar:
        for start in range(0, len(images), batch_size):
            batch = images[start:start + batch_size]
            rows.append(np.asarray(descriptor.describe(batch), dtype=np.float32))
            bar.update(len(batch))
    return np.concatenate(rows, axis=0)


#: Frames per forward pass while mapping: on a CPU one frame at a time is fastest per frame in
#: either engine (and needs the least memory); larger batches only spill the caches.
MAPPING_BATCH = 1


def _reuses_local_features(descriptor: Descriptor) -> bool:
    return all(callable(getattr(descriptor, name, None)) for name in ("local_features", "fit_features", "aggregate"))


def fit_and_describe(descriptor: Descriptor, images: Sequence[np.ndarray], fit_max_frames: int,
                     progress: bool = True) -> np.ndarray:
    """Fit the descriptor's vocabulary on evenly spaced frames (when it needs one) and describe
    every frame. Dense descriptors run the network once per frame: the vocabulary is fitted on
    the local features already extracted for the description (half the time of fitting and
    describing separately)."""
    if not _reuses_local_features(descriptor):
        if descriptor.needs_fit:
            descriptor.fit(vocabulary_frames(images, fit_max_frames))
        return describe_frames(descriptor, images, progress=progress)
    maps = []
    with tqdm(total=len(images), unit="frame", desc="extracting features", disable=not progress) as bar:
        for start in range(0, len(images), MAPPING_BATCH):
            batch = images[start:start + MAPPING_BATCH]
            maps.append(np.asarray(descriptor.local_features(batch)))
            bar.update(len(batch))
    features = np.concatenate(maps, axis=0)
    if descriptor.needs_fit:
        picks = np.arange(len(images)) if len(images) <= fit_max_frames else \
            np.linspace(0, len(images) - 1, fit_max_frames).round().astype(int)
        descriptor.fit_features(features[picks])
    return np.concatenate([np.asarray(descriptor.aggregate(features[i:i + 64]), dtype=np.float32)
                           for i in range(0, len(features), 64)], axis=0)


def node_columns(descriptor: Descriptor, keyframes: Sequence[np.ndarray],
                 progress: bool = True) -> Optional[np.ndarray]:
    """``(n_nodes, W, C)`` column profiles of the nodes' keyframes (steering by bearing,
    :mod:`descriptors.columns`), or None for a descriptor that gives none."""
    if not has_columns(descriptor):
        return None
    rows = []
    for image in tqdm(keyframes, unit="node", desc="column profiles", disable=not progress):
        rows.append(np.asarray(descriptor.describe_with_columns([image])[1], dtype=np.float32))
    return np.concatenate(rows, axis=0)


def vocabulary_frames(images: Sequence[np.ndarray], max_frames: int) -> list[np.ndarray]:
    """Evenly spaced frames of the walkthrough for fitting the vocabulary."""
    if len(images) <= max_frames:
        return list(images)
    picks = np.linspace(0, len(images) - 1, max_frames).round().astype(int)
    return [images[i] for i in picks]


def world_picture_of(world, appearance_seed: int = 0) -> Optional[WorldPicture]:
    """The top-down picture of a world (a WorldSpec or a shipped world's name), or ``None`` when
    the name is missing or unknown (a map made elsewhere is then drawn as a graph)."""
    if not world:
        return None
    from sim.topdown import render_topdown
    from sim.world_spec import WorldError
    from sim.worlds import load_world

    try:
        spec = load_world(world) if isinstance(world, str) else world
    except WorldError:
        return None
    td = render_topdown(spec, appearance_seed=appearance_seed)
    return WorldPicture(rgb=td.image, to_pixel=td.to_pixel)


def draw_saved_map(map_dir: str | Path) -> list[Path]:
    """Draw ``map.png`` and ``similarity.png`` of a saved map folder (``--mode show``).

    Simulator maps are drawn at their nodes' true positions over the world picture when the
    manifest names a world; other maps get a graph layout.
    """
    from maps.store import load_map

    loaded = load_map(map_dir)
    extra = loaded.extra or {}
    picture = world_picture_of(extra.get("world"), int(extra.get("appearance_seed", 0) or 0))
    return _draw_pictures(loaded.topomap, Path(map_dir), loaded.thumbnail, picture, loaded.similarity,
                          loaded.log, loaded.merged)


def _draw_pictures(topomap, map_dir: Path, thumbnail, world_picture, sample, log, merged) -> list[Path]:
    rejected = [(e.node_id, e.loop_candidate) for e in log.rejected_loop_events()] if log is not None else []
    paths = [draw_map_picture(topomap, map_dir / MAP_PICTURE, thumbnail=thumbnail, rejected_loops=rejected,
                              background=world_picture.rgb if world_picture else None,
                              world_to_pixel=world_picture.to_pixel if world_picture else None,
                              title=f"{len(topomap)} nodes, {len(topomap.loop_closures())} loop closures")]
    if sample is not None and log is not None:
        paths.append(draw_similarity_picture(sample, log, map_dir / SIMILARITY_PICTURE, merged=merged))
    return paths


def build_map_from_frames(frames: Iterable[MapFrame], descriptor: Descriptor, config: MappingConfig,
                          map_dir: str | Path, *, total: Optional[int] = None,
                          world_picture: Optional[WorldPicture] = None, fit_max_frames: int = 300,
                          source: str = "", extra: Optional[dict] = None, progress: bool = True,
                          viewer: Optional[ViewerTarget] = None) -> MapBuildResult:
    """Read ``frames``, build the map and save it to ``map_dir`` with ``map.png`` and ``similarity.png``.

    ``descriptor`` is fitted here when it needs a vocabulary. Returns the summary (also stored in
    the map's manifest with ``extra``, e.g. the world's name): frames read, nodes, loop closures,
    merges, metres when poses are known. ``viewer``: the build is also logged for the Rerun
    viewer there (:mod:`robot.viewer.mapping`).
    """
    map_dir = Path(map_dir)
    with tqdm(total=total or None, unit="frame", desc="reading", disable=not progress) as bar:
        kept: list[MapFrame] = []
        for frame in frames:
            kept.append(frame)
            bar.update(1)
    if len(kept) < 2:
        raise FrameSourceError(f"{source or 'the source'}: {len(kept)} frame(s) after sampling; a map needs at least 2")
    images = [f.rgb for f in kept]
    x = fit_and_describe(descriptor, images, fit_max_frames, progress=progress)
    poses = [f.true_pose for f in kept]
    made = build_map(x, config, frame_indices=[f.index for f in kept], stamps_s=[f.stamp_s for f in kept],
                     true_poses=poses if all(p is not None for p in poses) else None)
    odom = {f.index: f.odom_yaw_rad for f in kept if f.odom_yaw_rad is not None}
    gyro = {f.index: f.gyro_yaw_rad for f in kept if f.gyro_yaw_rad is not None}
    for node in made.topomap.nodes():   # the drive's heading at each node (turn hints, heading guard)
        made.topomap.set_odom_yaw(node.node_id, odom.get(node.keyframe_index))
        made.topomap.set_gyro_yaw(node.node_id, gyro.get(node.keyframe_index))
    by_index = {f.index: f.rgb for f in kept}
    thumbnails = {node.node_id: by_index[node.keyframe_index] for node in made.topomap.nodes()}
    columns = node_columns(descriptor, [by_index[node.keyframe_index] for node in made.topomap.nodes()],
                           progress=progress)
    sample = similarity_sample(x)
    merged = made.merge.merged if made.merge is not None else None
    summary = {**(extra or {}), "source": source, "frames_read": len(kept), **made.summary()}
    save_map(map_dir, made.topomap, identity=descriptor.identity, descriptor_state=descriptor.state_dict(),
             thresholds=made.thresholds, thumbnails=thumbnails,
             calibration=made.calibration.to_dict() if made.calibration is not None else None,
             log=made.log, similarity=sample, merged=merged, extra=summary, columns=columns)
    summary["map_bytes_per_node"] = int(map_size(map_dir).per_node_bytes)
    _draw_pictures(made.topomap, map_dir, thumbnails.get, world_picture, sample, made.log, merged)
    if viewer is not None:
        with Recording(viewer, f"map {source or map_dir.name}", blueprint=mapping_blueprint(rerun_sdk())) as rec:
            log_map_build(rec.rr, rec.stream, [f.stamp_s for f in kept], images, x, made, poses)
    return MapBuildResult(map_dir=map_dir, summary=summary)
