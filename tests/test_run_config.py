"""The run folder's configuration record (robot.bench.trials.write_run_config)."""

import argparse

from robot.bench import paper
from robot.bench.trials import RUN_CONFIG, config_digest, write_run_config
from robot.settings import load_stack_config


def test_the_run_config_keeps_every_field_whatever_the_defaults_become(tmp_path):
    """Read back, the record is the configuration it was written from (same digest), though it
    was not the default one; and it names every field, so a later default cannot change it."""
    mine = tmp_path / "mine.yaml"
    mine.write_text("navigation:\n  max_relocalisations: 2\n  heading_source: gyro\n")
    config = load_stack_config(mine)
    path = write_run_config(tmp_path / "run", config)
    assert path == tmp_path / "run" / RUN_CONFIG and path.read_text().startswith("# The configuration")
    again = load_stack_config(path)
    assert again == config and config_digest(again) == config_digest(config) != config_digest(load_stack_config())
    text = path.read_text()
    assert "heading_source: gyro" in text and "goal_by_likelihood:" in text and "t_milestone:" in text
    assert not list((tmp_path / "run").glob(f".{RUN_CONFIG}*"))           # no temporary left behind


def test_an_out_that_cannot_be_written_is_told_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    parser = argparse.ArgumentParser()
    paper.add_arguments(parser)
    args = parser.parse_args(["--out", str(blocker / "run"), "--quick", "--quiet"])
    assert paper.main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: --out {blocker / 'run'}: cannot write") and err.count("\n") == 1
    assert blocker.read_text() == "not a folder"


def test_replay_reads_the_run_folders_config_unless_told_another(tmp_path):
    from robot.bench.replay import replay_config

    episode = tmp_path / "run" / "episodes" / "x.json"
    other = tmp_path / "other.yaml"
    assert replay_config(episode, None) is None                      # no record: configs/default.yaml
    assert replay_config(episode, other) == other
    write_run_config(tmp_path / "run", load_stack_config())
    assert replay_config(episode, None) == (tmp_path / "run" / RUN_CONFIG).resolve()
    assert replay_config(episode, other) == other


def test_a_record_naming_a_field_removed_since_reads_without_it(tmp_path):
    """A run's record written before an addition was removed from the code still loads (a replay
    of a committed run must not stop), less that field, which comes back by name for a note; a
    user's --config file with an unknown field is still an error."""
    import yaml

    from core.configfile import ConfigError
    from robot.settings import load_run_record

    config = load_stack_config()
    path = write_run_config(tmp_path / "run", config)
    assert load_run_record(path) == (config, [])
    record = yaml.safe_load(path.read_text())
    record["navigation"]["gone_addition"] = {"enabled": True}
    record["navigation"]["supervisor"]["old_knob"] = 3
    record["retired_section"] = {"a": 1}
    path.write_text(yaml.safe_dump(record))
    again, dropped = load_run_record(path)
    assert again == config
    assert sorted(dropped) == ["navigation.gone_addition", "navigation.supervisor.old_knob", "retired_section"]
    try:
        load_stack_config(path)
    except ConfigError as exc:
        assert "unknown field" in str(exc)
    else:
        raise AssertionError("an unknown field in a --config file must be an error")
