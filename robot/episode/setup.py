"""Setting an episode up from a map: the descriptor the map was built with, and the thresholds.

* :func:`attach_descriptor` loads the map's vocabulary into the descriptor in use and refuses a
  map built with another descriptor (:class:`DescriptorMismatchError`);
* :func:`derive_thresholds` derives the navigation thresholds from the map's own statistics,
  placed by ``navigation.threshold_fractions``; :func:`configure_thresholds` applies them unless
  ``episode.thresholds_from_map`` is false (then ``navigation.thresholds`` are used as written);
* :func:`configure_heading` keeps ``navigation.heading_source`` unless the map lacks its headings.
* :func:`configure_bearing` keeps ``navigation.bearing`` on unless the map lacks column profiles;
* :func:`configure_navigation` does all three for a run and says on stderr what it changed.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from typing import Optional

import numpy as np

from controllers.config import NavigationConfig, Thresholds
from descriptors.base import Descriptor, DescriptorError
from maps.calibration import node_level_at
from maps.graph import MapError
from maps.store import LoadedMap
from robot.episode.config import EpisodeConfig


class DescriptorMismatchError(MapError):
    """The map was built with another descriptor (backend, settings, vocabulary or dimension)
    than the one in use; the message names the map folder and the difference."""


def attach_descriptor(loaded_map: LoadedMap, descriptor: Descriptor) -> Descriptor:
    """Load the map's vocabulary into ``descriptor`` (the one the configuration asks for) and check
    that it is the descriptor the map was built with; returns it.

    Raises :class:`DescriptorMismatchError` naming the map folder when the backend, settings,
    vocabulary or dimension differ.
    """
    mine, theirs = descriptor.identity, loaded_map.identity
    if mine.backend != theirs.backend or dict(mine.settings) != dict(theirs.settings):
        raise DescriptorMismatchError(
            f"map {loaded_map.path}: built with descriptor {theirs.backend!r} {dict(theirs.settings)}, but "
            f"the configuration uses {mine.backend!r} {dict(mine.settings)}; navigate with the map's "
            "descriptor or map again")
    try:
        descriptor.load_state(loaded_map.descriptor_state)
    except DescriptorError as exc:
        raise DescriptorMismatchError(f"map {loaded_map.path}: its descriptor state does not fit the "
                                      f"descriptor in use: {exc}") from None
    problem = theirs.mismatch(descriptor.identity)
    if problem:
        raise DescriptorMismatchError(f"map {loaded_map.path}: built with another descriptor than the one "
                                      f"in use (map's value last): {problem}")
    if descriptor.identity.dim and descriptor.identity.dim != loaded_map.topomap.dim:
        raise DescriptorMismatchError(f"map {loaded_map.path}: descriptors have dimension "
                                      f"{loaded_map.topomap.dim}, the descriptor in use {descriptor.identity.dim}")
    return descriptor


def map_self_similarity(loaded_map: LoadedMap) -> float:
    """How alike a view taken at a node is to that node, estimated from the walkthrough.

    The builder logs every frame's similarity to the node it stands at (``sim_to_node``); the
    frames right after a node are views from (nearly) the node's pose. The estimate is the median
    of that similarity over the first frame after each node (the first frame of every node's
    stretch); 1.0 when the map has no build log (the identical view).
    """
    log = loaded_map.log
    if log is None or log.n_frames < 3:
        return 1.0
    node = np.asarray(log.node)
    sims = np.asarray(log.sim_to_node, dtype=float)
    # frame k+1 is the first frame after frame k became (or returned to) a node
    firsts = np.flatnonzero(node[1:] != node[:-1]) + 2
    firsts = firsts[firsts < len(sims)]
    values = sims[firsts]
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else 1.0


def band_floor(loaded_map: LoadedMap, reference_sparsity: Optional[float]) -> float:
    """The lower edge of the thresholds' band: the similarity of two consecutive nodes of the
    map's walkthrough built at ``reference_sparsity`` (its calibration statistics), so that maps
    of one walkthrough at any spacing get the same thresholds; the map's own ``T_add_new_node``
    when ``reference_sparsity`` is None, is the map's own sparsity, or the map has no statistics."""
    own = float(loaded_map.thresholds.T_add_new_node)
    stats = (loaded_map.calibration or {}).get("stats") or {}
    if reference_sparsity is None or stats.get("sparsity") == reference_sparsity:
        return own
    level = node_level_at(stats, reference_sparsity)
    return own if level is None else float(np.clip(level, -1.0, 1.0))


def derive_thresholds(loaded_map: LoadedMap, navigation: NavigationConfig, *,
                      thirds_contrast: bool = True) -> Thresholds:
    """The navigation thresholds derived from the map (the default; ``EpisodeConfig``).

    Two consecutive nodes score about ``T_add_new_node`` against each other (the mapper added a
    node when the similarity to the last one fell below it; :func:`band_floor` takes the level of
    the reference sparsity), and a view taken at a node scores about :func:`map_self_similarity`
    against it. ``Thresholds.from_map`` places ``t_milestone``,
    ``t_change_node`` and ``t_lost`` as fractions of that band (``navigation.threshold_fractions``).
    ``t_limited_control`` is ``threshold_fractions.control_contrast`` when the voter sees contrast
    scores (``thirds_contrast``), else kept from ``navigation.thresholds``: the raw thirds' scale
    does not follow the map's node spacing.
    """
    t_add = band_floor(loaded_map, navigation.threshold_fractions.reference_sparsity)
    self_sim = map_self_similarity(loaded_map)
    if not self_sim > t_add + 0.02:
        self_sim = min(1.0, t_add + 0.1)   # a degenerate log: keep a usable band above T_add_new_node
    return Thresholds.from_map(t_add, self_sim, navigation.threshold_fractions,
                               t_limited_control=None if thirds_contrast
                               else navigation.thresholds.t_limited_control)


def configure_thresholds(loaded_map: LoadedMap, navigation: NavigationConfig,
                         episode: EpisodeConfig) -> NavigationConfig:
    """``navigation`` with the thresholds the episode uses: derived from the map when
    ``episode.thresholds_from_map``, else as written."""
    if not episode.thresholds_from_map:
        return navigation
    return replace(navigation, thresholds=derive_thresholds(loaded_map, navigation,
                                                            thirds_contrast=episode.thirds_contrast))


def configure_heading(loaded_map: LoadedMap, navigation: NavigationConfig) -> tuple[NavigationConfig, Optional[str]]:
    """``navigation`` with the heading source the episode uses, and a note when it is not the
    configured one: a map recorded before gyro headings were kept navigates on the wheel
    odometry's, since the map's and the robot's headings must come from one source."""
    topomap = loaded_map.topomap
    source = navigation.heading_source
    if source == "odometry" or topomap.headings(source) is not None or topomap.odom_headings is None:
        return navigation, None
    note = (f"the map {loaded_map.path} has no {source} headings (made before they were kept): the heading "
            "comes from the wheel odometry; rebuild the map from its recording to use the gyro's")
    return replace(navigation, heading_source="odometry"), note


def configure_bearing(loaded_map: LoadedMap, navigation: NavigationConfig) -> tuple[NavigationConfig, Optional[str]]:
    """``navigation`` with steering by bearing only where the map has column profiles, and a note
    when it was switched off: a map made before they were kept (or with a descriptor that gives
    none) is steered by the thirds, as before."""
    if not navigation.bearing.enabled or loaded_map.columns is not None:
        return navigation, None
    note = (f"the map {loaded_map.path} has no column profiles (made before 2026-12-07, or with a descriptor "
            "that gives none): the thirds steer; rebuild the map from its recording to steer by bearing")
    return replace(navigation, bearing=replace(navigation.bearing, enabled=False)), note


def configure_navigation(loaded_map: LoadedMap, navigation: NavigationConfig,
                         episode: EpisodeConfig) -> NavigationConfig:
    """The navigation configuration a run on ``loaded_map`` uses: thresholds from the map
    (:func:`configure_thresholds`), then the heading source and the bearing the map supports;
    each fallback is printed as one ``note:`` line on stderr."""
    nav, heading_note = configure_heading(loaded_map, configure_thresholds(loaded_map, navigation, episode))
    nav, bearing_note = configure_bearing(loaded_map, nav)
    for note in (heading_note, bearing_note):
        if note is not None:
            print(f"note: {note}", file=sys.stderr)
    return nav
