"""``exsur run --dry-run`` (``run_plan.py``): what a run would do, from its config alone where
the data is simulated, and what the CLI asks for (the logs' dry run is tested with them in
``tests/ingest/test_ingest_run.py``, the record against a run's ``config.toml`` there and in
``tests/test_pipeline.py``)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from excavator_surrogate.cli import main
from excavator_surrogate.pipeline import resolve_run
from excavator_surrogate.run_plan import plan_run


def _record(text: str) -> dict:
    return tomllib.loads(text[text.index("config.toml:\n") + 13 :])


def test_the_demo_is_planned_without_simulating(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--dry-run", "-q"]) == 0
    text = capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []  # nothing simulated, nothing written
    lines = text.splitlines()
    assert lines[0] == "preset: quick-hydraulic"
    assert lines[1].startswith(
        "data: simulated on the hydraulic stand-in (nothing simulated now): 100 train episode(s), 250.0 min"
    )
    # the demo's network is not the one the reference times were measured on: timed against
    # it on this computer (training/speed_probe.py)
    assert "2 training(s) (2 plain member(s)), 2 at a time in 1 round(s); 30 epochs" in text
    assert "s a training on the reference machine" in text and "no time estimate" not in text
    assert "scaled by this config's network (hidden = 64, feedback = 'free'" in text
    assert "each training capped at 600 s of wall time" in text
    rec = _record(text)
    assert rec["name"] == "quick-hydraulic" and rec["simulate"]["n_train"] == 100
    assert rec["train"]["epochs"] == 30 and "data" not in rec and "logs" not in rec


def test_the_cli_options_reach_the_plan(capsys) -> None:
    argv = ["run", "--preset", "quick", "--seed", "3", "--epochs", "7", "--members", "2"]
    assert main([*argv, "--set", "train.hidden=128", "--dry-run", "-q"]) == 0
    rec = _record(capsys.readouterr().out)
    assert rec["simulate"]["seed"] == rec["train"]["seed"] == 3
    assert (rec["train"]["epochs"], rec["train"]["members"], rec["train"]["hidden"]) == (7, 2, 128)


def test_baselines_side_by_side_or_one_after_the_other() -> None:
    """On 2 CPUs: single networks train side by side with their GRU baseline; a cleaning
    preset's 2-member surrogate and its raw-data baseline one after the other."""
    tiny = plan_run(resolve_run(preset="tiny", sets={"train": {"members": 1}}), cpus=2)
    assert "also trained with the same plan: GRU baseline; side by side" in tiny
    noload = plan_run(resolve_run(preset="paper-noload"), cpus=2)
    assert (
        "clean: rts; the models train on the cleaned data (and a baseline on the raw data)"
        in noload
    )
    assert "surrogate on the raw data; one model after the other" in noload
    # paper-noload's network is timed against the reference's (training/speed_probe.py)
    assert re.search(r"at once\): about \d+ s on the reference machine", noload)


def test_a_run_split_in_time_is_planned_on_its_parts() -> None:
    """The continuous log's preset: one 10-minute episode, cut 340 | 100 | 160 s."""
    text = plan_run(
        resolve_run(preset="continuous-dig", sets={"train": {"mode": "stateful"}}), cpus=2
    )
    assert (
        "1 train episode(s), 5.7 min; 1 val episode(s), 1.7 min; 1 test episode(s), 2.7 min" in text
    )


def test_running_needs_out_in_one_line(capsys) -> None:
    assert main(["run", "--preset", "tiny"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "exsur: error: --out DIR is required (or --dry-run to only print the plan)"


def test_a_set_the_run_would_not_read_is_refused_in_the_dry_run_too(capsys) -> None:
    argv = ["run", "--preset", "tiny", "--data", "whatever", "--set", "simulate.seed=1"]
    assert main([*argv, "--dry-run"]) == 2
    assert "simulate" in capsys.readouterr().err


def test_a_recipe_on_data_not_simulated_yet_is_not_guessed() -> None:
    """The recipe reads the data; before the data exists the plan says so instead."""
    text = plan_run(resolve_run(preset="real"), cpus=2)
    assert "recipe: chosen from the simulated data, so not before it exists" in text
    assert "planned work" not in text
