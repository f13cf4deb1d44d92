"""The stack configuration (robot.settings): a user's --config file is read over configs/default.yaml."""

import pytest

from core.configfile import ConfigError, read_yaml_mapping
from robot.settings import DEFAULT_CONFIG, load_stack_config


def test_a_partial_file_keeps_the_tuned_values_of_the_default_file(tmp_path):
    default = load_stack_config()
    tuned = read_yaml_mapping(DEFAULT_CONFIG)["navigation"]
    path = tmp_path / "mine.yaml"
    path.write_text("navigation:\n  supervisor: {goal_image_arrival: false}\n  belief: {confidence: 0.7}\n")
    mine = load_stack_config(path)
    assert mine.navigation.supervisor.goal_image_arrival is False
    assert mine.navigation.belief.confidence == 0.7
    # what the file leaves out is default.yaml's, not the dataclasses' neutral defaults
    assert mine.navigation.localiser.from_belief == tuned["localiser"]["from_belief"] == "initial"
    assert mine.navigation.belief.weight == tuned["belief"]["weight"] == default.navigation.belief.weight
    assert mine.navigation.belief.heading_bins == default.navigation.belief.heading_bins == 8
    assert mine.sim == default.sim and mine.mapping == default.mapping


def test_an_error_in_a_partial_file_names_it_and_the_field(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("navigation:\n  belief: {confidence: 2.0}\n")
    with pytest.raises(ConfigError) as err:
        load_stack_config(path)
    assert str(path) in str(err.value) and "navigation.belief.confidence" in str(err.value)


ABLATIONS = sorted((DEFAULT_CONFIG.parent / "ablation").glob("*.yaml"))


@pytest.mark.parametrize("path", ABLATIONS, ids=lambda p: p.stem)
def test_each_ablation_turns_off_something_of_the_default_navigation_only(path):
    default, ablated = load_stack_config(), load_stack_config(path)
    assert path.read_text().startswith("# Ablation"), "say what the ablation leaves out on its first line"
    assert ablated.navigation != default.navigation
    assert ablated.sim == default.sim and ablated.mapping == default.mapping
    assert ablated.descriptor == default.descriptor and ablated.episode == default.episode


def test_the_ablations_are_all_different():
    assert len(ABLATIONS) >= 9
    assert len({load_stack_config(p).navigation for p in ABLATIONS}) == len(ABLATIONS)
