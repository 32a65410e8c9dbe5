"""How fast this computer trained a model (``evaluate/pace.py``): the networks' ``log.csv``
summed against the reference machine and the cap; and the column the training writes."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from excavator_surrogate.data import Dataset
from excavator_surrogate.evaluate.pace import pace_markdown, training_pace
from excavator_surrogate.surrogate.checkpoint import read_checkpoint
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training import train
from excavator_surrogate.training.auto import auto_config
from excavator_surrogate.training.estimate import estimate_work


def _log(path: Path, rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _epochs(n: int, *, epoch_s: float, ref: float | str, val_s: float = 0.5) -> list[dict]:
    return [
        {
            "epoch": e,
            "time_s": (e + 1) * (epoch_s + val_s),
            "epoch_s": epoch_s,
            "val_s": val_s,
            "ref_epoch_s": ref,
        }
        for e in range(n)
    ]


def test_the_members_are_summed_and_the_ensembles_summary_skipped(tmp_path: Path) -> None:
    _log(tmp_path / "log.csv", [{"member": 0, "seed": 0, "epoch": 3, "val_error": 0.1}])
    _log(tmp_path / "plain" / "member_0" / "log.csv", _epochs(4, epoch_s=3.0, ref=2.0))
    _log(tmp_path / "prior" / "member_0" / "log.csv", _epochs(4, epoch_s=2.0, ref=2.0))
    _log(tmp_path / "another_run" / "log.csv", _epochs(9, epoch_s=9.0, ref=1.0))  # not this model's
    pace = training_pace(tmp_path)
    assert pace is not None
    assert (pace["networks"], pace["epochs"]) == (2, 8)
    assert pace["train_s"] == 20.0 and pace["reference_train_s"] == 16.0
    assert pace["pace"] == 1.25 and pace["longest_s"] == 14.0  # 4 x (3 + 0.5)
    assert [n["log"] for n in pace["per_network"]] == [
        "plain/member_0/log.csv",
        "prior/member_0/log.csv",
    ]
    text = pace_markdown(
        pace, {"members": [{"max_train_seconds": 28.0}, {"max_train_seconds": 28.0}]}
    )
    assert (
        "2 network(s), 8 epochs in all; their training steps took 20 s, 1.25x the reference machine's 16 s"
        in text
    )
    assert "The longest network ran 14 s of its 28-s cap (50 %): a run up to 2.00x slower" in text


def test_unknown_reference_cut_runs_and_no_logs(tmp_path: Path) -> None:
    _log(tmp_path / "old" / "log.csv", _epochs(2, epoch_s=1.0, ref=""))  # logs before the column
    pace = training_pace(tmp_path / "old")
    assert pace is not None and math.isnan(pace["pace"])
    text = pace_markdown(pace, {"max_train_seconds": 2.0, "budget_cut": True})
    assert "reference machine" not in text and "its 2-s cap cut it" in text
    through_json = {**pace, "pace": None, "reference_train_s": None}  # NaN as JSON writes it
    assert pace_markdown(through_json, {"max_train_seconds": 2.0, "budget_cut": True}) == text
    assert training_pace(tmp_path / "nothing") is None
    assert pace_markdown(None, {"budget_cut": False}) == "" == pace_markdown(pace, None)


def test_a_run_resumed_from_a_best_pt_sums_its_timed_epochs(tmp_path: Path) -> None:
    """best.pt holds no wall-clock entries, so a run resumed from it logs its earlier epochs
    without times: the sums cover the timed ones (they read 'nan s')."""
    rows = _epochs(2, epoch_s=1.0, ref=1.0) + _epochs(3, epoch_s=2.0, ref=1.0)
    for r in rows[:2]:
        r["epoch_s"] = r["ref_epoch_s"] = ""
    _log(tmp_path / "log.csv", rows)
    pace = training_pace(tmp_path)
    assert pace is not None
    assert (pace["epochs"], pace["timed_epochs"], pace["train_s"]) == (5, 3, 6.0)
    assert pace["pace"] == 2.0
    text = pace_markdown(pace, {"max_train_seconds": 20.0})
    assert "took 6 s (the 3 timed ones: a run resumed from a best.pt" in text and "nan" not in text


def test_the_recipes_network_logs_the_reference_time_and_best_pt_does_not(tmp_path: Path) -> None:
    """The recipe's 2 x 128 LSTM is the cost model's network: each log.csv row carries the
    reference machine's time for the epoch's training steps, the estimate's; ``best.pt``'s
    history has no column of time (the same bits on any load)."""
    spec = synthetic_spec(2)
    ds = Dataset(spec=spec)
    for i in range(3):
        ds.episodes["train"].append(synthetic_episode(spec, kind="step", n_step=300, seed=i))
    ds.episodes["val"].append(synthetic_episode(spec, kind="step", n_step=200, seed=9))
    cfg, _ = auto_config(
        ds,
        cpus=1,
        overrides={
            "epochs": 2,
            "members": 1,
            "tensorboard": False,
            "prior_choice": False,
            "static_map": False,
        },
    )
    est = estimate_work(cfg, ds, cpus=1)
    assert est is not None and not est.unmodelled
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    with open(best.parent / "log.csv") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["ref_epoch_s"]) for r in rows] == [pytest.approx(est.train_s, abs=1e-3)] * 2
    history = read_checkpoint(best)["history"]
    assert history and not any("ref_epoch_s" in r or "epoch_s" in r for r in history)
    assert training_pace(best.parent)["reference_train_s"] == pytest.approx(
        2 * est.train_s, abs=0.1
    )


def test_a_sub_second_cap_is_printed_as_set(tmp_path: Path) -> None:
    _log(tmp_path / "log.csv", _epochs(4, epoch_s=0.05, ref=1.0))
    pace = training_pace(tmp_path)
    assert pace is not None
    text = pace_markdown(pace, {"max_train_seconds": 0.3})
    assert f"ran {pace['longest_s']:.2g} s of its 0.3-s cap (" in text  # was "0 s of its 0-s cap"
    assert "its 0.3-s cap cut it" in pace_markdown(
        pace, {"max_train_seconds": 0.3, "budget_cut": True}
    )
