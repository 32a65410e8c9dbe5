"""Training: H-step loss, free-run model selection, stateful mode, resume, budget, config."""

from __future__ import annotations

import csv
import math
import shutil

import numpy as np
import pytest
import torch

from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.surrogate import free_run_error, load_checkpoint, read_checkpoint
from excavator_surrogate.surrogate.angles import omega_target
from excavator_surrogate.surrogate.rollout import window_rollout
from excavator_surrogate.training import TrainConfig, horizon_loss, train
from tests.helpers.surrogates import make_surrogate
from tests.helpers.training import tiny_dataset, tiny_train_config


def _smooth_l1(a: float, b: float) -> float:
    d = abs(a - b)
    return 0.5 * d * d if d < 1 else d - 0.5


@pytest.mark.parametrize("lambda_bias", [0.0, 0.3])
def test_h_step_loss_equals_hand_computed_loop(spec, episodes, lambda_bias):
    torch.manual_seed(1)
    sur = make_surrogate(spec, episodes, window=5, hidden=8)
    ep = episodes[0]
    W, H, dt = 5, 4, spec.dt
    ends = [6, 20, 33]
    x_all = sur.norm.encode_np(ep.theta, ep.u, spec)
    y_all = (
        omega_target(ep.theta, spec) - sur.norm.y_mean.double().numpy()
    ) / sur.norm.y_std.double().numpy()
    f32 = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    x_win = f32(np.stack([x_all[t - W + 1 : t + 1] for t in ends]))
    u_next = f32(np.stack([ep.u[t + 1 : t + H] for t in ends]))
    y = f32(np.stack([y_all[t + 1 : t + H + 1] for t in ends]))
    with torch.no_grad():
        y_hat, _ = window_rollout(
            sur.net, sur.norm, x_win, f32(ep.theta[ends]), u_next, n_horizon=H, dt=dt
        )
        loss = float(horizon_loss(y_hat, y, lambda_bias=lambda_bias))

    # hand-computed: python lists, one sample and one step at a time, float64 bookkeeping
    y_std, y_mean = sur.norm.y_std.double().numpy(), sur.norm.y_mean.double().numpy()
    total_vel, total_bias = 0.0, 0.0
    for t in ends:
        window = [x_all[k] for k in range(t - W + 1, t + 1)]
        theta = ep.theta[t].copy()
        preds = []
        for h in range(1, H + 1):
            with torch.no_grad():
                out = sur.net(f32(np.array(window))[None])[0].double().numpy()
            preds.append(out)
            theta = theta + dt * (out * y_std + y_mean)
            window = (
                [*window[1:], sur.norm.encode_np(theta, ep.u[t + h], spec)] if h < H else window
            )
        tgt = [y_all[t + h] for h in range(1, H + 1)]
        total_vel += sum(
            _smooth_l1(p[j], g[j]) for p, g in zip(preds, tgt) for j in range(spec.n_joint)
        )
        total_bias += float(np.sum((np.mean(preds, axis=0) - np.mean(tgt, axis=0)) ** 2))
    expected = total_vel / (len(ends) * H * spec.n_joint) + lambda_bias * total_bias / len(ends)
    assert loss == pytest.approx(expected, rel=1e-4, abs=1e-6)


@pytest.mark.parametrize(("mode", "factor"), [("windowed", 0.6), ("stateful", 0.75)])
def test_training_reduces_free_run_error(tmp_path, mode, factor):
    torch.manual_seed(0)
    ds = tiny_dataset(2, n_train=4, n_step=400)
    cfg = tiny_train_config(
        window=8,
        hidden=16,
        head_hidden=16,
        epochs=10,
        mode=mode,
        batch_size=32,
        seq_len=60,
        burn_in=8,
        tbptt=6,
        seq_batch=2,
        feedback="teacher",
        tensorboard=False,
        patience=10,
        seed=3,
    )
    untrained = make_surrogate(ds.spec, ds.train, mode=mode, window=8, hidden=16, seed=3)
    before = free_run_error(untrained, ds.val)["val_error"]
    best = train(cfg, ds, out=tmp_path / mode, show_progress=False)
    sur = load_checkpoint(best)
    assert sur.mode == mode
    after = free_run_error(sur, ds.val)["val_error"]
    assert after == pytest.approx(sur.metrics["val_error"], rel=1e-5)
    assert after < factor * before, (before, after)
    rows = list(csv.DictReader((tmp_path / mode / "log.csv").open()))
    assert len(rows) >= 1 and {"epoch", "time_s", "train_loss", "val_error", "lr"} <= set(rows[0])
    assert (tmp_path / mode / "last.pt").exists() and (tmp_path / mode / "config.toml").exists()


def test_resume_continues_epochs_and_budget_stops(tmp_path):
    ds = tiny_dataset(2, n_train=2, n_step=120)
    kw = dict(feedback="free", teacher_epochs=1)
    train(
        tiny_train_config(epochs=2, tensorboard=True, **kw),
        ds,
        out=tmp_path / "a",
        show_progress=False,
    )
    assert (tmp_path / "a" / "tb").is_dir()
    hist = read_checkpoint(tmp_path / "a" / "last.pt")["history"]
    assert all(math.isfinite(h["train_loss"]) for h in hist)
    cfg3 = tiny_train_config(epochs=3, **kw)
    train(cfg3, ds, out=tmp_path / "a", resume=tmp_path / "a" / "last.pt", show_progress=False)
    hist = read_checkpoint(tmp_path / "a" / "last.pt")["history"]
    assert [h["epoch"] for h in hist] == [0, 1, 2]
    with pytest.raises(CheckpointError, match="architecture"):
        bad = tiny_train_config(hidden=9, epochs=3, **kw)
        train(bad, ds, out=tmp_path / "b", resume=tmp_path / "a" / "last.pt", show_progress=False)
    quick = TrainConfig(
        window=5, hidden=8, head_hidden=8, epochs=50, max_train_seconds=1e-3, tensorboard=False
    )
    train(quick, ds, out=tmp_path / "c", show_progress=False)
    assert len(read_checkpoint(tmp_path / "c" / "last.pt")["history"]) == 1


def test_resuming_into_another_folder_keeps_the_resumed_runs_best(tmp_path):
    ds = tiny_dataset(2, n_train=2, n_step=120)
    # no epoch after the first beats it; a resume continues the run's settings, more epochs
    train(tiny_train_config(epochs=2, min_delta=0.99), ds, out=tmp_path / "a", show_progress=False)
    best_a = read_checkpoint(tmp_path / "a" / "best.pt")
    never = tiny_train_config(epochs=4, min_delta=0.99)
    train(never, ds, out=tmp_path / "b", resume=tmp_path / "a" / "last.pt", show_progress=False)
    best_b = read_checkpoint(tmp_path / "b" / "best.pt")
    assert best_b["metrics"]["val_error"] == best_a["metrics"]["val_error"]
    for k, v in best_a["state_dict"].items():
        assert torch.equal(best_b["state_dict"][k], v), k
    # a last.pt alone, its best.pt not beside it: the best is one of the resumed run's epochs
    (tmp_path / "lone").mkdir()
    shutil.copyfile(tmp_path / "a" / "last.pt", tmp_path / "lone" / "last.pt")
    train(never, ds, out=tmp_path / "c", resume=tmp_path / "lone" / "last.pt", show_progress=False)
    assert read_checkpoint(tmp_path / "c" / "best.pt")["metrics"]["epoch"] >= 2


def test_train_config_from_preset_and_validation():
    cfg = TrainConfig.from_preset(
        {"train": {"hidden": 32, "mode": "stateful"}}, epochs=7, seed=None
    )
    assert (cfg.hidden, cfg.mode, cfg.epochs, cfg.seed) == (32, "stateful", 7, 0)
    with pytest.raises(ConfigError, match="unknown key"):
        TrainConfig.from_preset({"train": {"hiden": 32}})
    with pytest.raises(ConfigError, match="seq_len"):
        TrainConfig(seq_len=10, burn_in=10)
    assert math.isfinite(TrainConfig().lr)


def test_weight_average_competes_for_the_best_checkpoint(tmp_path):
    ds = tiny_dataset(2, n_train=2, n_step=160)
    cfg = tiny_train_config(seq_batch=2, epochs=4, patience=4, ema_decay=0.9)
    best = train(cfg, ds, out=tmp_path, show_progress=False)
    rows = list(csv.DictReader((tmp_path / "log.csv").open()))
    assert {r["weights"] for r in rows} <= {"raw", "ema"} and len(rows) == 4
    for r in rows:  # the epoch's score is the better of the two candidates
        assert float(r["val_error"]) == pytest.approx(
            min(float(r["val_error_raw"]), float(r["val_error_ema"]))
        )
    k = max(i for i, r in enumerate(rows) if r["best"] == "1")
    sur = load_checkpoint(best)
    # best.pt holds exactly the weights that earned its score
    assert free_run_error(sur, ds.val)["val_error"] == pytest.approx(
        float(rows[k]["val_error"]), rel=1e-5
    )
    # the average is a different set of weights from the raw ones it follows
    ema_row = rows[-1]
    assert float(ema_row["val_error_raw"]) != float(ema_row["val_error_ema"])


def test_a_knob_the_mode_does_not_read_is_an_error():
    with pytest.raises(ConfigError, match=r"horizon = 10 is read only by mode = \"windowed\""):
        TrainConfig(mode="stateful", horizon=10)
    with pytest.raises(ConfigError, match="seq_len"):
        TrainConfig(mode="windowed", seq_len=60)
    TrainConfig(mode="stateful", horizon=1)  # the default is not a setting
    cfg = TrainConfig(mode="stateful", seq_len=60, burn_in=10).for_mode("windowed")
    assert (cfg.mode, cfg.seq_len, cfg.burn_in) == ("windowed", 150, 30)
    # --mode on the command line drops the preset's knobs of the other mode
    preset = {"train": {"mode": "stateful", "seq_len": 60, "window": 7}}
    cfg = TrainConfig.from_preset(preset, mode="windowed")
    assert (cfg.mode, cfg.seq_len, cfg.window) == ("windowed", 150, 7)
    bases = TrainConfig.mode_bases({"train": {"seq_len": 60, "horizon": 3}})
    assert (bases["windowed"].horizon, bases["windowed"].seq_len) == (3, 150)
    assert (bases["stateful"].horizon, bases["stateful"].seq_len) == (1, 60)


def test_a_resume_with_another_seed_is_refused_and_a_resume_is_recorded(tmp_path):
    """``--resume last.pt`` with a forgotten ``--seed 5`` continued silently as seed 0, and
    the record described a run that never happened.  Another seed (or learning rate ...) is
    refused in one line naming last.pt's values; the cap, the epochs and the thread count may
    change, and the record says which checkpoint the run continued, and loads back."""
    import tomllib

    from excavator_surrogate.stages import build_configs, load_preset

    ds = tiny_dataset(2, n_train=2, n_step=120)
    train(tiny_train_config(epochs=2, seed=5), ds, out=tmp_path / "a", show_progress=False)
    last = tmp_path / "a" / "last.pt"
    other = tiny_train_config(epochs=3, lr=0.01)  # seed 0: forgotten
    with pytest.raises(ConfigError) as e:
        train(other, ds, out=tmp_path / "x", resume=last, show_progress=False)
    line = str(e.value)
    assert line.startswith(f"--resume {last}: it was trained with ") and "\n" not in line
    assert "lr = 0.001 (here 0.01)" in line and "seed = 5 (here 0)" in line
    more = tiny_train_config(epochs=3, seed=5, max_train_seconds=600.0, num_threads=2)
    train(more, ds, out=tmp_path / "b", resume=last, show_progress=False)
    record = tmp_path / "b" / "config.toml"
    assert tomllib.loads(record.read_text())["resume"] == {"from": str(last.resolve()), "epoch": 2}
    assert build_configs(load_preset(record), sections=["train"])["train"] == more
