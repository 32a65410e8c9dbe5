"""The planned work of a config before it trains (``training/estimate.py``): the same
numbers the recipe plans with (``training/plan.py``), counted the way the pool runs them."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training.auto import auto_config
from excavator_surrogate.training.batches import make_data, sequence_cap
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.estimate import (
    SpeedRatio,
    WorkEstimate,
    describe_work,
    estimate_work,
    val_epoch_s,
)
from excavator_surrogate.training.modes import make_mode
from excavator_surrogate.training.plan import (
    PLAN_SHARE,
    POST_SHARE,
    STEP_NET,
    VAL_STEP_S,
    epoch_cost_s,
    member_budget_s,
    trainings,
)
from tests.helpers.surrogates import make_surrogate
from tests.surrogate.test_auto import _with_gear  # a gear that changes by turns


def _dataset(lengths: list[int], *, val: list[int]) -> Dataset:
    spec = synthetic_spec(3)
    ds = Dataset(spec=spec)
    for i, n in enumerate(lengths):
        ds.episodes["train"].append(synthetic_episode(spec, kind="step", n_step=n, seed=i))
    for i, n in enumerate(val):
        ds.episodes["val"].append(synthetic_episode(spec, kind="step", n_step=n, seed=90 + i))
    return ds


@pytest.mark.parametrize(
    ("lengths", "val", "budget"),
    [
        ([600] * 100, [200] * 6, 540.0),  # many runs (the h1 shape)
        ([8000], [2000], 540.0),  # one long log, one validation segment
        ([8000], [2000], 60.0),  # the same, squeezed: the budget binds
        ([3200], [2000], 600.0),  # a short log: the data bound the epochs
    ],
)
def test_the_estimate_is_the_recipes_own_plan(lengths, val, budget):
    """Trainings, rounds and caps as the recipe budgets them (``plan.trainings``,
    ``member_budget_s``), its epochs, and a planned time within its share: the cap leaves a
    computer at least (1 - POST_SHARE) / PLAN_SHARE times slower room to finish."""
    ds = _dataset(lengths, val=val)
    cfg, why = auto_config(ds, cpus=2, budget_s=budget)
    est = estimate_work(cfg, ds, cpus=2)
    assert est is not None and est.epochs == cfg.epochs and est.cap_s == cfg.max_train_seconds
    assert est.trainings == trainings(cfg.members, probe=False, kinds=cfg.prior_choice)
    assert est.workers == cfg.member_workers and est.rounds == math.ceil(est.trainings / 2)
    share = member_budget_s(cfg.members, budget, cpus=2, probe=False, kinds=cfg.prior_choice)
    assert est.cap_s == pytest.approx((1 - POST_SHARE) * share)
    # the plan budgets a validation of every epoch, as two separate free runs at the plan's
    # price; the estimate counts the epochs the loop validates, at today's price
    val_steps = max(val)
    plan_s = est.epochs * epoch_cost_s(
        est.n_seq, seq_len=cfg.seq_len, seq_batch=int(STEP_NET["seq_batch"]), val_steps=val_steps
    )
    assert est.val_s == pytest.approx(val_epoch_s(val_steps, len(val)))
    assert est.training_s <= plan_s <= PLAN_SHARE * share + 1e-9 or est.epochs == 1
    assert est.headroom >= (1 - POST_SHARE) / PLAN_SHARE - 1e-9 or est.epochs == 1
    planned = next(w for w in why if "epochs planned" in w)
    assert f"{est.n_seq} sub-sequences per epoch" in planned
    assert f"about {plan_s:.0f} s per member" in planned
    assert est.total_s == pytest.approx(est.rounds * est.training_s)
    assert 1 <= est.validated <= est.epochs
    assert est.unmodelled == ()  # the recipe trains the network the times were measured on


@pytest.mark.parametrize(
    ("select", "validated"),
    [
        ({}, 6),
        ({"select_after": 0.5, "select_smooth": 1}, 4),
        ({"train_on_val": True}, 1),
        ({"select_after": 0.5, "select_smooth": 1, "lr_schedule": "plateau"}, 6),
    ],
)
def test_the_validated_epochs_are_those_the_loop_validates(tmp_path, select, validated):
    """Every epoch; on one short segment the second half of the plan (less the epochs its
    smoothed score reads); where validation is trained on, the last epoch alone: counted
    from a training's own ``log.csv`` (the recipe's cosine schedule; the plateau schedule
    validates every epoch, as it steps on the error)."""
    import csv

    from excavator_surrogate.training import train
    from tests.helpers.training import tiny_dataset, tiny_train_config

    ds = tiny_dataset(2, n_train=2, n_step=120)
    cfg = tiny_train_config(**{"epochs": 6, "seq_batch": 4, "lr_schedule": "cosine", **select})
    est = estimate_work(cfg, ds, cpus=1)
    assert est is not None
    train(cfg, ds, out=tmp_path, show_progress=False)
    with open(tmp_path / "log.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == cfg.epochs
    ran = sum(math.isfinite(float(r["val_error"])) for r in rows)  # NaN: not validated
    assert est.validated == ran == validated


def test_the_input_probe_and_a_single_cpu_are_counted():
    ds = _with_gear(_dataset([8000], val=[2000]))
    # the kinds chosen on validation, so the plain networks may drive a joint: the gear is
    # tried (spanning every joint, the recipe would ignore it without a trial)
    tried = {"prior_drive": "validation"}
    cfg, _ = auto_config(ds, cpus=2, overrides=tried)
    assert cfg.exogenous == "choose"  # 2 more networks decide it, in the same budget
    est = estimate_work(cfg, ds, cpus=2)
    assert est is not None and est.probes == 2
    assert est.trainings == trainings(cfg.members, probe=True, kinds=cfg.prior_choice) == 8
    assert est.cap_s == pytest.approx((1 - POST_SHARE) * 540 / est.rounds)
    dual, _ = auto_config(ds, cpus=2, overrides={**tried, "input_dropout": 0.5})
    both = estimate_work(dual, ds, cpus=2)  # every network learns both ways: no probe
    assert both is not None and both.probes == 0 and both.trainings == 6
    one = estimate_work(replace(cfg, member_workers=0), ds, cpus=1)
    assert one is not None and one.workers == 1 and one.rounds == one.trainings
    lines = describe_work(est)
    assert "decide the exogenous inputs" in lines[0] and f"{est.rounds} round(s)" in lines[0]


def test_no_cap_and_the_windowed_mode_say_so():
    ds = _dataset([600] * 10, val=[200])
    cfg, _ = auto_config(ds, cpus=2, overrides={"max_train_seconds": 0})
    est = estimate_work(cfg, ds, cpus=2)
    assert est is not None and est.cap_s == 0 and est.headroom == math.inf
    assert "no wall-time cap" in describe_work(est)[-1]
    windowed = cfg.for_mode("windowed")
    assert estimate_work(windowed, ds) is None
    assert describe_work(None)[0].startswith("no estimate")


def test_a_network_the_times_were_not_measured_on_gets_no_time():
    """The demo's preset (64 units, free-run feedback, batches of 64, the velocity input)
    trains at another speed than the reference's per-step cost: its plan, not its time."""
    ds = _dataset([600] * 10, val=[200])
    cfg, _ = auto_config(ds, cpus=2)
    other = replace(cfg, hidden=64, feedback="free", seq_batch=64, velocity_input=True)
    est = estimate_work(other, ds, cpus=2)
    assert est is not None and est.epochs == cfg.epochs and est.cap_s == cfg.max_train_seconds
    assert est.unmodelled == (
        "hidden = 64",
        "feedback = 'free'",
        "seq_batch = 64",
        "velocity_input = True",
    )
    lines = describe_work(est)
    assert "training(s)" in lines[0] and f"{est.epochs} epochs" in lines[0]
    assert lines[1].startswith("no time estimate") and "hidden = 64" in lines[1]
    assert lines[1].endswith("(`--dry-run` times it against them on this computer)")
    assert (
        lines[2]
        == f"each training capped at {est.cap_s:.0f} s of wall time; a run cut by it says so"
    )
    assert not any("reference machine (" in ln or "slower than" in ln for ln in lines)


def test_a_measured_speed_ratio_times_another_network():
    """``with_speed`` scales the reference network's epoch (in its batches of 16) by the
    measured ratios; the lines give the time, the ratios and the headroom under the cap."""
    ds = _dataset([600] * 10, val=[200])
    cfg, _ = auto_config(ds, cpus=2)
    other = replace(cfg, hidden=64, seq_batch=64)
    est = estimate_work(other, ds, cpus=2)
    ref = estimate_work(cfg, ds, cpus=2)
    assert est is not None and ref is not None and not est.timed
    # the unscaled times are the reference network's on the same sub-sequences
    assert (est.train_s, est.val_s) == (ref.train_s, ref.val_s)
    timed = est.with_speed(SpeedRatio(train=0.5, val=0.25, seconds=4.6))
    assert timed.timed and timed.unmodelled == est.unmodelled
    assert timed.train_s == pytest.approx(0.5 * ref.train_s)
    assert timed.val_s == pytest.approx(0.25 * ref.val_s)
    assert timed.training_s == pytest.approx(
        est.epochs * 0.5 * ref.train_s + est.validated * 0.25 * ref.val_s
    )
    assert timed.headroom == pytest.approx(2 * ref.headroom, rel=0.5)  # about half the time
    lines = describe_work(timed)
    assert lines[1].startswith(f"about {timed.training_s:.0f} s a training on the reference")
    assert "hidden = 64, seq_batch = 64) against the reference's" in lines[2]
    assert "0.50x on the training steps, 0.25x on validation (a 5-s probe" in lines[2]
    assert f"up to {timed.headroom:.2f}x slower than the reference" in lines[3]
    with pytest.raises(ValueError, match="already scaled"):
        timed.with_speed(SpeedRatio(train=1.0, val=1.0))


def test_a_free_run_feedback_config_prices_its_teacher_forced_epochs_apart():
    """A ``feedback = "free"`` config trains its first ``teacher_epochs`` teacher-forced (about
    half the cost of a free-run epoch): the estimate counts them (never more than the
    epochs), times them by their own ratio, and a ratio without one is refused."""
    ds = _dataset([600] * 10, val=[200])
    cfg, _ = auto_config(ds, cpus=2)
    free = replace(cfg, hidden=64, feedback="free", teacher_epochs=3)
    est = estimate_work(free, ds, cpus=2)
    ref = estimate_work(cfg, ds, cpus=2)
    assert est is not None and ref is not None and not est.timed
    assert est.teacher_epochs == 3 and est.teacher_train_s == est.train_s == ref.train_s
    assert est.steps_s == pytest.approx(est.epochs * ref.train_s)  # unscaled: all alike
    with pytest.raises(ValueError, match="must time them"):
        est.with_speed(SpeedRatio(train=0.5, val=0.25))
    timed = est.with_speed(SpeedRatio(train=0.5, val=0.25, teacher=0.3, seconds=6.0))
    steps = (est.epochs - 3) * 0.5 * ref.train_s + 3 * 0.3 * ref.train_s
    assert timed.steps_s == pytest.approx(steps)
    assert timed.training_s == pytest.approx(steps + est.validated * 0.25 * ref.val_s)
    lines = describe_work(timed)
    assert f"({timed.steps_s:.0f} s of training steps," in lines[1]
    assert (
        "0.50x on the training steps (0.30x in the 3 teacher-forced epoch(s) before the "
        "free-run feedback), 0.25x on validation" in lines[2]
    )
    # every epoch is teacher-forced in the recipe's feedback, whatever teacher_epochs says
    taught = estimate_work(replace(cfg, hidden=64, teacher_epochs=3), ds, cpus=2)
    assert taught is not None and taught.teacher_epochs == 0
    assert (
        "teacher-forced" not in describe_work(taught.with_speed(SpeedRatio(train=0.5, val=0.25)))[2]
    )
    short = estimate_work(replace(free, epochs=2), ds, cpus=2)
    assert short is not None and short.teacher_epochs == 2


def test_validation_is_priced_per_sample_of_the_longest_run_and_per_run_batched():
    """A validated epoch costs ``val_epoch_s``: per sample of the longest validation run, more
    with more runs batched (h1-dev's 24 cost about 4x one segment's per sample), well below
    the plan's two separate runs on one long segment; a run too short for the window is not
    free-run, so not counted."""
    seg_ds = _dataset([8000], val=[2000])
    seg = estimate_work(auto_config(seg_ds, cpus=2)[0], seg_ds, cpus=2)
    assert seg is not None and seg.val_s == pytest.approx(val_epoch_s(2000, 1))
    assert seg.val_s < 2 * 2000 * VAL_STEP_S / 4  # the plan's price, 4-6x today's
    many_ds = _dataset([600] * 40, val=[640] * 23 + [300, 20])  # 20 samples: under the window
    cfg, _ = auto_config(many_ds, cpus=2)
    many = estimate_work(cfg, many_ds, cpus=2)
    assert many is not None and many.val_s == pytest.approx(val_epoch_s(640, 24))
    assert 3.5 < val_epoch_s(1, 24) / val_epoch_s(1, 1) < 5


def test_a_cap_on_an_epochs_samples_and_on_validation_runs_is_counted():
    """``epoch_samples`` cuts an epoch's sub-sequences as ``Stateful.batches`` cuts its
    starts, ``val_steps`` the validation free runs: the recipe's network keeps its time."""
    ds = _dataset([600] * 10, val=[300])
    cfg, _ = auto_config(ds, cpus=2)
    full = estimate_work(cfg, ds, cpus=2)
    per_seq = cfg.seq_len - cfg.burn_in + 1
    capped = estimate_work(replace(cfg, epoch_samples=3 * per_seq, val_steps=100), ds, cpus=2)
    assert full is not None and capped is not None and capped.timed
    assert full.n_seq > 3 and capped.n_seq == 3
    assert capped.train_s < full.train_s and capped.val_s == pytest.approx(full.val_s / 3)


def test_the_estimates_epoch_cap_is_the_one_the_training_applies():
    """``epoch_samples``: the stateful mode's epoch holds as many sub-sequences as the
    estimate counts (both call ``batches.sequence_cap``)."""
    ds = _dataset([400] * 6, val=[200])
    cfg = TrainConfig(mode="stateful", seq_len=40, burn_in=10, seq_batch=4, epoch_samples=250)
    sur = make_surrogate(ds.spec, ds.train, mode="stateful")
    mode = make_mode(cfg, make_data(ds.train, sur.norm, torch.device("cpu")), sur)
    drawn = sum(len(b) for b in mode.batches(np.random.default_rng(0), 1))
    est = estimate_work(cfg, ds, cpus=1)
    assert est is not None and drawn == est.n_seq == sequence_cap(250, seq_len=40, burn_in=10)
    assert est.n_seq == 250 // 31 < estimate_work(replace(cfg, epoch_samples=0), ds).n_seq


def test_a_cap_shorter_than_the_plan_is_a_warning_with_the_epoch_it_cuts_at():
    """A cap below the planned time was printed as "a computer up to 0.05x slower than the
    reference trains every network whole": the dry run now says the cap will cut training
    even on the reference machine, and after about which epoch."""
    est = WorkEstimate(
        n_seq=10,
        epochs=10,
        teacher_epochs=0,
        members=1,
        map_correcting=0,
        probes=0,
        workers=1,
        train_s=1.0,
        val_s=1.0,
        teacher_train_s=1.0,
        validated=5,
        cap_s=7.5,
    )
    # epochs end at 1, 2, 3, 4, 5 s, then 7, 9 s (validated): the one ending at 9 s is the last
    assert est.headroom < 1 and est.epochs_in_cap == 7
    line = describe_work(est)[-1]
    assert line.startswith("warning: each training is capped at 7.5 s of wall time, less than")
    assert "cut training after about 7 of 10 epochs even on the reference machine" in line
    assert "slower than the reference" not in line
    whole = replace(est, cap_s=est.training_s)  # exactly the plan: every epoch runs
    assert whole.epochs_in_cap == 10 and "slower than the reference" in describe_work(whole)[-1]
