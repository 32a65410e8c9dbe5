"""Selection that stays sound on a short validation split (``select_after``, ``select_smooth``),
and the selected epoch averaged with the last where validation cannot vouch for the other
commands (``average_last``)."""

from __future__ import annotations

import math

import pytest
import torch

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, read_checkpoint
from excavator_surrogate.surrogate.validation import free_run_errors
from excavator_surrogate.training import loop, train
from excavator_surrogate.training.selection import (
    averaged,
    first_eligible,
    first_validated,
    selection_score,
)
from tests.helpers.surrogates import tiny_surrogate
from tests.helpers.training import tiny_dataset, tiny_train_config


def test_a_lucky_epoch_in_a_noisy_stretch_does_not_win():
    noisy = [1.0, 0.4, 1.1, 0.9]  # epoch 1 is a lucky draw among bad neighbours
    calm = [0.6, 0.6, 0.6, 0.6]
    assert selection_score(noisy[:2], smooth=0) == 0.4  # the old rule: its own error
    best_noisy = min(selection_score(noisy[: k + 1], smooth=2) for k in range(len(noisy)))
    best_calm = min(selection_score(calm[: k + 1], smooth=2) for k in range(len(calm)))
    assert best_calm < best_noisy
    # the saved weights must be good themselves, not only their neighbours
    assert selection_score([0.5, 0.5, 0.5, 2.0], smooth=3) == 2.0
    # a diverged epoch counts as +inf, and the score is finite again once it leaves the window
    assert selection_score([0.5, math.nan, 0.5], smooth=2) == 0.5
    assert selection_score([math.nan, math.nan, 0.5], smooth=2) == math.inf


def test_first_eligible_epoch():
    assert first_eligible(110, 0.0) == 0
    assert first_eligible(110, 0.5) == 55
    assert first_eligible(3, 0.5) == 1


def test_validation_trained_on_lets_only_the_last_epoch_compete():
    assert first_eligible(110, 0.5, last_only=True) == 109
    assert first_eligible(1, 0.0, last_only=True) == 0
    assert first_validated(110, 0.0, smooth=0, plateau=False, last_only=True) == 109
    assert first_validated(110, 0.0, smooth=4, plateau=False, last_only=True) == 105


def test_train_on_val_trains_on_validation_and_keeps_the_last_epoch(tmp_path):
    """The validation episodes are training data too; only the last epoch is validated and
    competes, so best.pt holds it (the better of its raw and averaged weights)."""
    data = tiny_dataset(2, n_train=2, n_step=120)
    kw = dict(epochs=4, ema_decay=0.9, lr_schedule="cosine")
    best = train(
        tiny_train_config(train_on_val=True, **kw), data, out=tmp_path / "on", show_progress=False
    )
    ck = read_checkpoint(best)
    rows = ck["history"]
    assert [r["validated"] for r in rows] == [0, 0, 0, 1]
    assert [r["best"] for r in rows] == [0, 0, 0, 1] and ck["metrics"]["epoch"] == 3
    off = read_checkpoint(train(tiny_train_config(**kw), data, out=tmp_path / "off"))
    # more training samples per epoch than without validation
    assert rows[0]["n_sample"] > off["history"][0]["n_sample"]


def test_train_on_val_cut_by_the_cap_validates_the_epoch_it_ends_on(tmp_path):
    """A wall-time cap that ends training before the planned last epoch makes the epoch it
    ends on the last: validated and kept, with its score, and the run says it was cut."""
    data = tiny_dataset(2, n_train=2, n_step=120)
    cfg = tiny_train_config(train_on_val=True, epochs=5, max_train_seconds=1e-3)
    ck = read_checkpoint(train(cfg, data, out=tmp_path / "cut", show_progress=False))
    (row,) = ck["history"]
    assert row["validated"] == 1 and row["best"] == 1 and ck["metrics"]["epoch"] == 0
    assert math.isfinite(ck["metrics"]["val_error"])
    assert ck["metrics"]["training"]["budget_cut"] is True


def test_train_on_val_stops_only_on_the_cut_it_validated(tmp_path, monkeypatch):
    """With train_on_val the stop for the cap is decided once, when the epoch's training
    ends: a deadline passed later in the epoch's bookkeeping (after the check) does not stop
    training after an epoch nobody validated; the next epoch is the cut one, validated and
    kept."""
    from types import SimpleNamespace

    from excavator_surrogate.training import parallel

    clock = {"now": 0.0}
    fake = SimpleNamespace(monotonic=lambda: clock["now"])
    monkeypatch.setattr(loop, "time", fake)
    monkeypatch.setattr(parallel, "time", fake)

    def late(epoch, row):  # the deadline passes after epoch 0's cut check, before its stop
        clock["now"] = 1e9
        return False

    data = tiny_dataset(2, n_train=2, n_step=120)
    cfg = tiny_train_config(
        train_on_val=True, epochs=5, max_train_seconds=100.0, lr_schedule="cosine"
    )
    out = train(cfg, data, out=tmp_path / "late", show_progress=False, on_epoch=late)
    ck = read_checkpoint(out)
    rows = ck["history"]
    assert [r["validated"] for r in rows] == [0, 1] and [r["best"] for r in rows] == [0, 1]
    assert ck["metrics"]["epoch"] == 1 and math.isfinite(ck["metrics"]["val_error"])
    assert ck["metrics"]["training"]["budget_cut"] is True


def test_first_validated_epoch():
    # the first competitor's score reads the `smooth` epochs before it, no earlier one
    assert first_validated(110, 0.5, smooth=4, plateau=False) == 51
    assert first_validated(110, 0.0, smooth=4, plateau=False) == 0
    assert first_validated(4, 0.5, smooth=4, plateau=False) == 0
    # the plateau schedule steps on every epoch's validation error
    assert first_validated(110, 0.5, smooth=4, plateau=True) == 0


def test_skipping_early_validation_changes_no_weight_and_no_score(tmp_path, monkeypatch):
    cfg = tiny_train_config(epochs=6, select_after=0.5, select_smooth=1, lr_schedule="cosine")
    data = tiny_dataset(2, n_train=2, n_step=120)
    fast = read_checkpoint(train(cfg, data, out=tmp_path / "fast", show_progress=False))
    rows = fast["history"]
    assert [r["validated"] for r in rows] == [0, 0, 1, 1, 1, 1]  # eligible from 3, smooth 1
    assert all(math.isnan(r["val_error"]) for r in rows[:2])
    # the reference: every epoch validated
    monkeypatch.setattr(loop, "validation_start", lambda cfg: 0)
    ref = read_checkpoint(train(cfg, data, out=tmp_path / "ref", show_progress=False))
    assert all(r["validated"] == 1 for r in ref["history"])
    assert fast["metrics"]["epoch"] == ref["metrics"]["epoch"]
    for a, b in zip(rows[2:], ref["history"][2:]):
        assert a["val_error"] == b["val_error"]
        both_nan = math.isnan(a["select_score"]) and math.isnan(b["select_score"])  # not eligible
        assert a["select_score"] == b["select_score"] or both_nan
    for k, v in ref["state_dict"].items():
        assert torch.equal(fast["state_dict"][k], v), k


def test_only_epochs_after_select_after_compete(tmp_path):
    cfg = tiny_train_config(epochs=4, select_after=0.5, select_smooth=1)
    best = train(
        cfg, tiny_dataset(2, n_train=2, n_step=120), out=tmp_path / "s", show_progress=False
    )
    ck = read_checkpoint(best)
    assert ck["metrics"]["epoch"] >= 2
    rows = ck["history"]
    assert [math.isnan(r["select_score"]) for r in rows[:2]] == [True, True]
    assert all(r["best"] == 0 for r in rows[:2])
    # the score of an eligible epoch is the larger of its error and the recent median
    for k in (2, 3):
        recent = sorted(r["val_error"] for r in rows[k - 1 : k + 1])
        want = max(rows[k]["val_error"], sum(recent) / 2)
        assert rows[k]["select_score"] == pytest.approx(want, rel=1e-12)


def test_averaged_is_the_mean_of_the_two_weights_parameter_by_parameter():
    a, b = tiny_surrogate(seed=0), tiny_surrogate(seed=1)
    before = {k: v.clone() for k, v in a.net.state_dict().items()}
    avg = averaged(a, b)
    for (name, p), q, r in zip(a.net.named_parameters(), b.net.parameters(), avg.net.parameters()):
        torch.testing.assert_close(r, (p + q) / 2, rtol=0, atol=1e-7, msg=name)
    for k, v in a.net.state_dict().items():  # the inputs are untouched
        assert torch.equal(v, before[k]), k
    assert avg.norm is not a.norm  # a copy


def test_average_last_writes_the_selected_epoch_averaged_with_the_last(tmp_path):
    data = tiny_dataset(2, n_train=2, n_step=120)
    kw = dict(epochs=4, ema_decay=0.9, lr_schedule="cosine")
    plain = train(tiny_train_config(**kw), data, out=tmp_path / "plain", show_progress=False)
    sel, last = load_checkpoint(plain), load_checkpoint(tmp_path / "plain" / "last.pt")
    best = train(
        tiny_train_config(average_last=True, **kw), data, out=tmp_path / "avg", show_progress=False
    )
    got = load_checkpoint(best)
    # the same training (same data and seed): the average of the plain run's two checkpoints
    for name, p in got.net.named_parameters():
        want = (
            dict(sel.net.named_parameters())[name] + dict(last.net.named_parameters())[name]
        ) / 2
        torch.testing.assert_close(p, want, rtol=0, atol=1e-6, msg=name)
    rec = got.metrics["averaged_with_last"]
    assert rec["epoch"] == sel.metrics["epoch"] and rec["last_epoch"] == 3
    assert rec["val_error"] == sel.metrics["val_error"]
    # its metrics are the average's own validation free run
    val_eps = data.val
    want = free_run_errors([got], val_eps)[0]["val_error"]
    assert got.metrics["val_error"] == pytest.approx(want, rel=1e-5)
    assert read_checkpoint(best)["history"] == read_checkpoint(plain)["history"]
    # resumed after the plan (no epoch left): best.pt is not averaged a second time
    again = train(
        tiny_train_config(average_last=True, **kw),
        data,
        out=tmp_path / "avg",
        resume=tmp_path / "avg" / "last.pt",
        show_progress=False,
    )
    for p, q in zip(load_checkpoint(again).net.parameters(), got.net.parameters()):
        assert torch.equal(p, q)


@pytest.mark.parametrize(
    "bad",
    [
        {"select_after": 1.0},
        {"select_after": float("nan")},
        {"select_smooth": -1},
        {"average_last": 1},
    ],
)
def test_bad_selection_options_are_one_line(bad):
    with pytest.raises(ConfigError, match=next(iter(bad))):
        tiny_train_config(**bad)
