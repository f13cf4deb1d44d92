"""The offline belief run's settings sweep (robot.bench.belief); the run itself over a replayed
episode is tested with the paper harness (tests/test_bench_paper.py, slow lane)."""

import pytest

from controllers.config import BeliefConfig
from robot.bench.belief import BeliefBenchError, sweep


def test_every_combination_of_the_settings_runs_in_order():
    configs = sweep(BeliefConfig(), ["heading_bins=1,8", "weight=0.05,0.2"])
    assert [(c.heading_bins, c.weight) for c in configs] == [(1, 0.05), (1, 0.2), (8, 0.05), (8, 0.2)]
    assert all(c.cell_m == BeliefConfig().cell_m for c in configs)
    assert sweep(BeliefConfig(weight=0.3), []) == [BeliefConfig(weight=0.3)]


@pytest.mark.parametrize("setting, message", [
    ("colour=1", "no field 'colour'"),
    ("weight", "expected FIELD=VALUE"),
    ("weight=", "expected FIELD=VALUE"),
    ("heading_bins=2.5", "'2.5' is not a valid int"),
    ("weight=abc", "'abc' is not a valid float"),
    ("weight=0.1,2", "weight=2.0: weight must be"),
])
def test_a_bad_setting_is_named(setting, message):
    with pytest.raises(BeliefBenchError, match=message):
        sweep(BeliefConfig(), [setting])
