"""Navigation configuration: validation, map-derived thresholds, YAML loading, action speeds."""

import dataclasses

import pytest

from controllers.actions import Action, action_velocity
from controllers.config import (
    ActionSpeeds,
    LocaliserConfig,
    NavigationConfig,
    SimilarityFilterConfig,
    SupervisorConfig,
    ThresholdFractions,
    Thresholds,
)
from core.configfile import ConfigError, from_mapping, load_config, to_mapping
from core.hal import VelocityCommand


def test_map_thresholds_use_the_configured_fractions():
    """The fractions live in one place (ThresholdFractions, navigation.threshold_fractions)."""
    th = Thresholds.from_map(0.45, 0.85)                          # band 0.4
    assert th.t_milestone == pytest.approx(0.45 + ThresholdFractions().milestone * 0.4)
    assert th.t_change_node == pytest.approx(0.45 + ThresholdFractions().change_node * 0.4)
    assert th.t_lost == pytest.approx(0.45 - ThresholdFractions().lost * 0.4)
    other = Thresholds.from_map(0.45, 0.85, ThresholdFractions(milestone=0.5, change_node=0.3, lost=0.2))
    assert (other.t_milestone, other.t_change_node, other.t_lost) == pytest.approx((0.65, 0.57, 0.37))


@pytest.mark.parametrize("t_add,self_sim", [(0.3, 1.0), (0.45, 0.8), (0.6, 0.75), (0.1, 0.4)])
def test_map_thresholds_are_ordered_inside_the_band(t_add, self_sim):
    th = Thresholds.from_map(t_add, self_sim)
    assert th.t_lost < t_add < th.t_change_node < th.t_milestone < self_sim


def test_map_thresholds_for_the_thirds():
    assert Thresholds.from_map(0.4, 0.9).t_limited_control == ThresholdFractions().control_contrast
    assert Thresholds.from_map(0.4, 0.9, ThresholdFractions(control_contrast=0.7)).t_limited_control == 0.7
    assert Thresholds.from_map(0.4, 0.9, t_limited_control=0.3).t_limited_control == 0.3


@pytest.mark.parametrize("kwargs,match", [
    (dict(t_add_new_node=0.8, self_similarity=0.7), "self_similarity"),
    (dict(t_add_new_node=1.4), "t_add_new_node"),
])
def test_map_thresholds_reject_bad_statistics(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Thresholds.from_map(**kwargs)


@pytest.mark.parametrize("cls,kwargs,match", [
    (Thresholds, dict(t_milestone=1.2), "t_milestone"),
    (Thresholds, dict(t_lost=0.7), "t_lost"),
    (Thresholds, dict(t_limited_control=float("nan")), "t_limited_control"),
    (SimilarityFilterConfig, dict(measurement_std=0.0), "measurement_std"),
    (SupervisorConfig, dict(window_ahead=0), "window_ahead"),
    (SupervisorConfig, dict(lost_patience_ticks=2.5), "lost_patience_ticks"),
    (LocaliserConfig, dict(full_turn_rad=-1.0), "full_turn_rad"),
    (LocaliserConfig, dict(relocalise_hops=-1), "relocalise_hops"),
    (LocaliserConfig, dict(relocalise_heading_tolerance_deg=0.0), "relocalise_heading_tolerance_deg"),
    (LocaliserConfig, dict(relocalise_heading_tolerance_deg=270), "relocalise_heading_tolerance_deg"),
    (ActionSpeeds, dict(left=VelocityCommand(0.0, -0.5)), "left.w_radps must be positive"),
    (ActionSpeeds, dict(forward=VelocityCommand(0.0, 0.0)), "forward.v_mps must be positive"),
    (ActionSpeeds, dict(forward_right=VelocityCommand(-0.1, -0.3)), "forward_right.v_mps"),
    (ActionSpeeds, dict(search_rotate=VelocityCommand(0.0, -0.5)), "search_rotate.w_radps"),
    (NavigationConfig, dict(max_relocalisations=-1), "max_relocalisations"),
    (ThresholdFractions, dict(milestone=1.2), "milestone"),
    (ThresholdFractions, dict(milestone=0.1, change_node=0.2), "change_node"),
])
def test_bad_fields_are_named(cls, kwargs, match):
    with pytest.raises(ValueError, match=match):
        cls(**kwargs)


def test_loads_from_yaml_and_errors_name_file_and_field(tmp_path):
    good = tmp_path / "navigation.yaml"
    good.write_text("thresholds:\n  t_milestone: 0.7\n  t_change_node: 0.6\n"
                    "speeds:\n  forward: {v_mps: 0.3, w_radps: 0.0}\n"
                    "supervisor:\n  window_ahead: 4\n")
    config = load_config(NavigationConfig, good)
    assert config.thresholds.t_milestone == 0.7 and config.supervisor.window_ahead == 4
    assert config.speeds.forward == VelocityCommand(0.3, 0.0)
    assert from_mapping(NavigationConfig, to_mapping(config)) == config      # round trip
    bad = tmp_path / "bad.yaml"
    bad.write_text("thresholds:\n  t_lost: 0.65\n")
    with pytest.raises(ConfigError) as info:
        load_config(NavigationConfig, bad)
    assert "bad.yaml" in str(info.value) and "thresholds" in str(info.value)
    assert "t_lost (0.65) must be below" in str(info.value)


def test_with_thresholds_replaces_only_the_thresholds():
    config = NavigationConfig(max_relocalisations=2)
    th = Thresholds.from_map(0.3, 0.9)
    new = config.with_thresholds(th)
    assert new.thresholds == th and new.max_relocalisations == 2
    with pytest.raises(dataclasses.FrozenInstanceError):
        new.max_relocalisations = 3


def test_every_action_maps_to_its_velocity():
    speeds = ActionSpeeds()
    assert action_velocity(Action.FORWARD, speeds) == speeds.forward
    assert action_velocity(Action.LEFT, speeds).w_radps > 0
    assert action_velocity(Action.RIGHT, speeds).w_radps < 0
    fl, fr = action_velocity(Action.FORWARD_LEFT, speeds), action_velocity(Action.FORWARD_RIGHT, speeds)
    assert fl.v_mps > 0 and fl.w_radps > 0 and fr.v_mps > 0 and fr.w_radps < 0
    assert action_velocity(Action.SEARCH_ROTATE, speeds) == speeds.search_rotate
    for action in Action:
        if action is Action.RETRACE:          # a recent command negated: no speed of its own
            continue
        cmd = action_velocity(action, speeds)
        assert isinstance(cmd, VelocityCommand)
        assert cmd.is_zero == (not action.moves)
    with pytest.raises(TypeError, match="expected an Action"):
        action_velocity("forward", speeds)


def test_the_heading_source_is_odometry_or_gyro():
    assert NavigationConfig().heading_source == "odometry"
    assert NavigationConfig(heading_source="gyro").heading_source == "gyro"
    with pytest.raises(ValueError, match="heading_source"):
        NavigationConfig(heading_source="compass")
