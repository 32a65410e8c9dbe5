"""Timing a config's network against the recipe's (``training/speed_probe.py``): what the dry
runs scale the reference machine's times by.  Only the ratios' form is tested here, never a
time (tests do not time; the probe runs in tenths of a second here, see ``conftest.py``)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from excavator_surrogate.training import speed_probe
from excavator_surrogate.training.auto import auto_config
from excavator_surrogate.training.estimate import SpeedRatio, estimate_work
from excavator_surrogate.training.speed_probe import measure_speed, timed_estimate
from tests.training.test_estimate import _dataset


def test_the_probe_gives_ratios_and_leaves_the_global_state_alone():
    """Positive, finite ratios for a free-run-trained 16-unit network; torch's global random
    stream and the thread count are as they were, so a training after a dry
    run draws what it would have drawn."""
    cfg, _ = auto_config(_dataset([600] * 6, val=[300]), cpus=2)
    cfg = replace(cfg, hidden=16, head_hidden=16, feedback="free", seq_len=40, burn_in=10)
    torch.manual_seed(7)
    threads = torch.get_num_threads()
    ratio = measure_speed(cfg, n_joint=3)
    after = torch.rand(3)
    torch.manual_seed(7)
    assert torch.equal(after, torch.rand(3))
    assert torch.get_num_threads() == threads
    assert all(math.isfinite(r) and r > 0 for r in (ratio.train, ratio.val, ratio.seconds))
    assert ratio.teacher is not None and math.isfinite(ratio.teacher) and ratio.teacher > 0


def test_a_free_run_feedback_is_timed_in_its_teacher_forced_epochs_too(monkeypatch):
    """The bursts of a ``feedback = "free"`` config with ``teacher_epochs`` train as epoch 0
    (teacher-forced, :mod:`~excavator_surrogate.training.modes`) beside those past its
    warm-up; a teacher-forced config is timed once, with no warm-up ratio."""
    epochs: list[int] = []
    burst = speed_probe.ThrowawayNetwork.train_burst

    def spy(self, seconds, *, epoch=None):
        epochs.append(self.free_epoch if epoch is None else epoch)
        return burst(self, seconds, epoch=epoch)

    monkeypatch.setattr(speed_probe.ThrowawayNetwork, "train_burst", spy)
    cfg, _ = auto_config(_dataset([600] * 6, val=[300]), cpus=2)
    small = replace(cfg, hidden=16, head_hidden=16, seq_len=40, burn_in=10)
    free = replace(small, feedback="free", teacher_epochs=2)
    assert speed_probe.PROBE_EPOCH >= free.teacher_epochs  # the main bursts run free
    ratio = measure_speed(free, n_joint=3)
    assert ratio.teacher is not None
    timed = epochs[2:]  # after each network's warm-up burst
    assert timed.count(0) == timed.count(speed_probe.PROBE_EPOCH) == 2 * speed_probe.PROBE_ROUNDS
    epochs.clear()
    assert measure_speed(small, n_joint=3).teacher is None
    assert set(epochs) == {speed_probe.PROBE_EPOCH}
    # a warm-up past PROBE_EPOCH: the config's main bursts train as its first free-run epoch
    # (the reference network's, teacher-forced throughout, as PROBE_EPOCH)
    long = replace(free, epochs=20, teacher_epochs=12)
    epochs.clear()
    measure_speed(long, n_joint=3)
    assert set(epochs[2:]) == {0, speed_probe.PROBE_EPOCH, 12}
    assert epochs[2:].count(12) == speed_probe.PROBE_ROUNDS
    assert long.teacher_forced(11) and not long.teacher_forced(12)


def test_only_a_network_the_cost_model_does_not_cover_is_probed(monkeypatch):
    ds = _dataset([600] * 6, val=[300])
    cfg, _ = auto_config(ds, cpus=2)
    calls: list[int] = []

    def fake(c, *, n_joint):
        calls.append(n_joint)
        return SpeedRatio(train=0.5, val=0.5, seconds=1.0)

    monkeypatch.setattr(speed_probe, "measure_speed", fake)
    est = estimate_work(cfg, ds, cpus=2)
    assert timed_estimate(est, cfg, n_joint=3) is est and calls == []  # the recipe's network
    assert timed_estimate(None, cfg) is None and calls == []  # the windowed mode's estimate
    capped = replace(cfg, epoch_samples=500)  # the recipe's network in a shorter epoch
    est = estimate_work(capped, ds, cpus=2)
    assert timed_estimate(est, capped) is est and calls == []
    gpu = replace(cfg, hidden=64, device="cuda:7")  # the reference times are a CPU's
    est = estimate_work(gpu, ds, cpus=2)
    assert timed_estimate(est, gpu) is est and calls == []
    other = replace(cfg, hidden=64)
    est = estimate_work(other, ds, cpus=2)
    timed = timed_estimate(est, other, n_joint=3)
    assert calls == [3] and timed is not None and timed.timed
    assert timed.train_s == pytest.approx(0.5 * est.train_s)
