"""The statistics that python -m robot.bench perf prints, on samples whose answers are known."""

import pytest

from robot.bench.perf import summary_ms


def test_summary_of_a_known_sample():
    s = summary_ms([5.0, 1.0, 3.0, 2.0, 4.0, 100.0])
    assert s["median"] == pytest.approx(3.5)
    assert s["p90"] == pytest.approx(52.5)          # half way between 5 and 100 (linear interpolation)
    assert s["mean"] == pytest.approx(115.0 / 6)
    assert s["n"] == 6 and s["min"] == 1.0


def test_one_slow_step_moves_the_mean_and_the_p90_but_not_the_median():
    steady = [10.0] * 19
    s = summary_ms(steady + [1000.0])
    assert s["median"] == 10.0 and s["p90"] == pytest.approx(10.0) and s["mean"] == pytest.approx(59.5)
    s = summary_ms(steady[:9] + [1000.0])
    assert s["p90"] == pytest.approx(109.0)
