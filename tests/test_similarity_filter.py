"""The vectorised similarity filter is filterpy's scalar Kalman filter, node by node."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from controllers.config import SimilarityFilterConfig
from controllers.similarity_filter import SimilarityFilter


def filterpy_reference(series: np.ndarray, config: SimilarityFilterConfig) -> np.ndarray:
    kf = KalmanFilter(dim_x=1, dim_z=1)
    kf.F[:] = 1.0
    kf.H[:] = 1.0
    kf.Q[:] = config.process_std ** 2
    kf.R[:] = config.measurement_std ** 2
    kf.x[:] = series[0]
    kf.P[:] = config.measurement_std ** 2
    out = [series[0]]
    for z in series[1:]:
        kf.predict()
        kf.update(z)
        out.append(kf.x[0, 0])
    return np.array(out)


def test_matches_filterpy_for_every_node():
    rng = np.random.default_rng(3)
    config = SimilarityFilterConfig(process_std=0.02, measurement_std=0.07)
    drift = np.cumsum(rng.normal(0, 0.02, (60, 5)), axis=0)
    rows = np.clip(0.5 + drift + rng.normal(0, 0.07, (60, 5)), -1, 1)
    bank = SimilarityFilter(5, config)
    ours = np.array([bank.update(row) for row in rows])
    for j in range(5):
        np.testing.assert_allclose(ours[:, j], filterpy_reference(rows[:, j], config), rtol=0, atol=1e-12)


def test_single_spike_is_attenuated_and_step_is_followed():
    config = SimilarityFilterConfig()
    bank = SimilarityFilter(1, config)
    for _ in range(50):
        bank.update(np.array([0.4]))
    spiked = bank.update(np.array([0.95]))[0]
    assert spiked - 0.4 < 0.25 * (0.95 - 0.4)          # steady gain is about 0.18
    for _ in range(20):                                # a real change is followed
        level = bank.update(np.array([0.8]))[0]
    assert level > 0.78


def test_first_update_starts_at_the_measurement_and_reset_forgets():
    bank = SimilarityFilter(3)
    np.testing.assert_allclose(bank.update(np.array([0.1, 0.5, 0.9])), [0.1, 0.5, 0.9])
    assert bank.started
    bank.reset()
    assert not bank.started
    np.testing.assert_allclose(bank.update(np.array([0.7, 0.7, 0.7])), [0.7, 0.7, 0.7])


def test_bad_rows_are_rejected():
    bank = SimilarityFilter(3)
    with pytest.raises(ValueError, match="expected 3 similarities"):
        bank.update(np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        bank.update(np.array([0.1, np.nan, 0.2]))
    with pytest.raises(ValueError, match="at least one node"):
        SimilarityFilter(0)
