"""``python -m robot.bench compare``: run folders side by side, on small hand-written runs."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from robot.bench.compare import CompareError, config_changes, format_rows, read_episodes, row
from robot.bench.trials import Trial


def _episode(run: Path, route: str, trial: int, success: bool, collisions: int = 0, method: str = "ours") -> None:
    t = Trial(world="hospital", route=route, method=method, trial=trial, map_dir="maps/hospital-s0.5",
              appearance_seed=trial + 1, start_x_m=0.0, start_y_m=0.0, start_yaw_deg=0.0, offset_m=0.0,
              offset_yaw_deg=0.0, shortest_length_m=10.0)
    metrics = {"success": success, "success_0_5m": success, "spl": 0.9 if success else 0.0,
               "final_distance_m": 0.2 if success else 5.0, "relocalisations": 0, "collisions": collisions,
               "steps": 100}
    folder = run / "episodes"
    folder.mkdir(parents=True, exist_ok=True)
    episode = {"trial": asdict(t), "metrics": metrics}
    (folder / f"hospital_{route}_{method}_{trial}.json").write_text(json.dumps(episode))


@pytest.fixture()
def runs(tmp_path):
    reference, ablated = tmp_path / "reference", tmp_path / "no-guard"
    for trial in range(3):
        _episode(reference, "easy", trial, True)
        _episode(reference, "hard", trial, trial != 2, collisions=1)
        _episode(reference, "hard", trial, False, method="sptm")
        _episode(ablated, "easy", trial, trial == 0)
        _episode(ablated, "hard", trial, True, collisions=2 if trial == 0 else 0)
    (reference / "config.yaml").write_text("navigation:\n  heading_guard: {enabled: true}\n  bearing: {turn: 0.25}\n")
    (ablated / "config.yaml").write_text("navigation:\n  heading_guard: {enabled: false}\n  bearing: {turn: 0.25}\n")
    return reference, ablated


def test_a_row_per_run_with_the_configuration_it_changes(runs):
    reference, ablated = runs
    routes = ["hospital:easy", "hospital:hard"]
    first = row(reference, reference, read_episodes(reference, "ours"), routes)
    second = row(ablated, reference, read_episodes(ablated, "ours"), routes)
    assert first["changes"] == "" and second["changes"] == "navigation.heading_guard.enabled=False"
    assert first["sr_per_route"] == {"hospital:easy": 1.0, "hospital:hard": pytest.approx(2 / 3, abs=1e-4)}
    assert second["sr_per_route"] == {"hospital:easy": pytest.approx(1 / 3, abs=1e-4), "hospital:hard": 1.0}
    assert first["sr"] == pytest.approx(5 / 6, abs=1e-4) and second["sr"] == pytest.approx(2 / 3, abs=1e-4)
    assert first["collisions_per_episode"] == 0.5 and second["collisions_per_episode"] == pytest.approx(1 / 3, abs=1e-3)
    assert first["trials"] == 6 and first["steps"] == 600
    table = format_rows([first, second, first], routes, "ours").splitlines()
    assert "(reference)" in table[2] and "navigation.heading_guard.enabled=False" in table[3]
    assert "(none)" in table[4]            # a later run that changes nothing is not the reference


def test_the_first_trials_only_and_one_method_only(runs):
    reference, _ = runs
    assert len(read_episodes(reference, "ours")) == 6
    assert {e["trial"]["trial"] for e in read_episodes(reference, "ours", trials=1)} == {0}
    assert all(e["trial"]["method"] == "sptm" for e in read_episodes(reference, "sptm"))
    # trial paths are resolved against the run folder, as the harness keeps them relative
    assert read_episodes(reference, "ours")[0]["trial"]["map_dir"] == str(reference / "maps/hospital-s0.5")


def test_bad_run_folders_are_named(tmp_path, runs):
    with pytest.raises(CompareError, match="no episodes/ folder"):
        read_episodes(tmp_path, "ours")
    broken = tmp_path / "broken"
    (broken / "episodes").mkdir(parents=True)
    (broken / "episodes" / "x.json").write_text("{not json")
    with pytest.raises(CompareError, match="x.json: not an episode file"):
        read_episodes(broken, "ours")
    assert config_changes(tmp_path, runs[0]) == "?"       # no config.yaml to compare
