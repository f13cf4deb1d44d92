"""Navigation thresholds derived from a map: one walkthrough mapped at any sparsity gets the same."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from controllers.config import NavigationConfig, ThresholdFractions
from descriptors.base import DescriptorIdentity
from maps.calibration import node_level_at
from maps.config import MappingConfig
from maps.pipeline import build_map
from maps.store import LoadedMap
from robot.episode.setup import band_floor, derive_thresholds
from tests.map_synthetic import landmark_route

IDENTITY = DescriptorIdentity(backend="test-projection", settings={}, vocabulary_sha256="ab" * 32, dim=256)


@pytest.fixture(scope="module")
def maps():
    route = landmark_route(seed=0, stand_frames=0)
    out = {}
    for sparsity in (0.25, 0.5, 0.75):
        made = build_map(route.descriptors, MappingConfig(sparsity=sparsity), true_poses=route.poses,
                         stamps_s=route.stamps_s)
        out[sparsity] = LoadedMap(path=Path(f"s{sparsity}"), topomap=made.topomap, identity=IDENTITY,
                                  descriptor_state={}, thresholds=made.thresholds, schema_version=1,
                                  calibration=made.calibration.to_dict(), log=made.log)
    return out


def navigation(reference_sparsity):
    return NavigationConfig(threshold_fractions=ThresholdFractions(reference_sparsity=reference_sparsity))


def test_maps_of_one_walkthrough_at_any_sparsity_get_the_same_thresholds(maps):
    assert len(maps[0.25].topomap) > len(maps[0.5].topomap) > len(maps[0.75].topomap)
    ref = {s: derive_thresholds(m, navigation(0.5)) for s, m in maps.items()}
    own = {s: derive_thresholds(m, navigation(None)) for s, m in maps.items()}
    for field in ("t_milestone", "t_change_node", "t_lost"):
        values = [getattr(ref[s], field) for s in maps]
        # the band's top (a view's similarity to its own node) is measured per map: nearly equal
        assert max(values) - min(values) < 0.03, (field, values)
    # with each map's own node level, the dense map asks for far more than the sparse one
    assert own[0.25].t_milestone - own[0.75].t_milestone > 0.1
    assert own[0.25].t_milestone > ref[0.25].t_milestone and own[0.75].t_lost < ref[0.75].t_lost
    # the map built at the reference sparsity keeps exactly its own thresholds
    assert ref[0.5] == own[0.5]


def test_band_floor_is_the_calibrated_node_level_or_the_map_s_own(maps):
    dense = maps[0.25]
    stats = dense.calibration["stats"]
    assert band_floor(dense, 0.25) == dense.thresholds.T_add_new_node
    assert band_floor(dense, 0.5) == pytest.approx(maps[0.5].thresholds.T_add_new_node, abs=1e-6)
    assert band_floor(dense, 0.75) == pytest.approx(node_level_at(stats, 0.75))
    assert band_floor(dense, 0.75) == pytest.approx(maps[0.75].thresholds.T_add_new_node, abs=1e-6)
    assert band_floor(dense, None) == dense.thresholds.T_add_new_node
    # a map without calibration statistics (explicit thresholds, older maps): its own level
    assert band_floor(replace(dense, calibration=None), 0.5) == dense.thresholds.T_add_new_node
    assert node_level_at({"s_top": 0.9}, 0.5) is None


def test_reference_sparsity_is_checked():
    with pytest.raises(ValueError, match="reference_sparsity"):
        ThresholdFractions(reference_sparsity=1.5)
