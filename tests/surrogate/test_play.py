"""Command play features (valve hysteresis memory): operator, encoding, every rollout path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.surrogate import rollout, rollout_reference
from excavator_surrogate.surrogate.checkpoint import (
    checkpoint_dict,
    load_checkpoint,
    save_checkpoint,
)
from excavator_surrogate.surrogate.command_state import (
    command_rows_seq,
    command_rows_step,
    play_np,
    play_step,
)
from excavator_surrogate.surrogate.features import Normalization, encode_np, scale_commands_np
from excavator_surrogate.surrogate.rollout import window_rollout
from excavator_surrogate.training import TrainConfig
from tests.helpers.surrogates import make_surrogate
from tests.helpers.training import train_tiny_free_run

PLAY = (0.05, 0.2)


def test_play_operator_remembers_the_side_a_command_came_from():
    # one joint: a hold at 0.6 reached from below, then the same hold reached from above
    us = np.concatenate(
        [np.linspace(0, 0.6, 7), np.full(30, 0.6), np.full(5, 1.0), np.full(30, 0.6)]
    )
    z = play_np(us[:, None], (0.05,))[:, 0, 0]
    f = (z - us) / 0.05
    assert z[36] == pytest.approx(0.55) and f[36] == pytest.approx(-1.0)  # from below, held
    assert z[-1] == pytest.approx(0.65) and f[-1] == pytest.approx(1.0)  # from above, held
    # inside the band the state does not move
    us2 = np.array([0.0, 0.04, -0.04, 0.0])
    np.testing.assert_allclose(play_np(us2[:, None], (0.05,))[:, 0, 0], 0.0)


def test_play_step_equals_the_plain_loop(rng):
    us = rng.uniform(-1, 1, (3, 50, 4))
    ref = play_np(us, PLAY)
    z = torch.zeros(3, len(PLAY), 4, dtype=torch.float64)
    b = torch.tensor(PLAY, dtype=torch.float64)
    for k in range(50):
        z = play_step(z, torch.as_tensor(us[:, k]), b)
        np.testing.assert_allclose(z.numpy(), ref[:, k], atol=1e-12)


def test_play_np_equals_one_sample_at_a_time_to_the_bit(rng):
    # the reference computes each sample's bounds inside the loop; play_np all at once
    us = rng.uniform(-1, 1, (2, 3, 40, 4))
    z0 = rng.uniform(-0.5, 0.5, (2, 3, len(PLAY), 4))
    b = np.asarray(PLAY)[:, None]
    for start in (None, z0):
        z = np.zeros((2, 3, len(PLAY), 4)) if start is None else start.copy()
        ref = np.empty((2, 3, 40, len(PLAY), 4))
        for k in range(40):
            x = us[..., k, None, :]
            z = np.minimum(np.maximum(z, x - b), x + b)
            ref[..., k, :, :] = z
        assert np.array_equal(play_np(us, PLAY, z0=start), ref)
    # a state shared by every episode broadcasts over them
    shared = play_np(us, PLAY, z0=z0[0, 0])
    assert np.array_equal(shared[1, 2], play_np(us[1, 2], PLAY, z0=z0[0, 0]))


@pytest.mark.parametrize("n_step", [0, 1, 40])
@pytest.mark.parametrize(
    ("widths", "n_line", "n_rest"),
    [
        (PLAY, 0, 0),
        ((), 4, 0),
        (PLAY, 3, 0),
        ((), 1, 2),
        (PLAY, 2, 2),
        ((), 0, 2),
        ((), 0, 0),
    ],
)
def test_command_rows_seq_equals_one_sample_at_a_time_to_the_bit(
    rng, n_step, widths, n_line, n_rest
):
    # the delay line is a window of the commands and the rows after it pass through: copies,
    # so the whole sequence at once equals the sample-by-sample step exactly
    b = torch.tensor(widths, dtype=torch.float32)
    n_command = len(widths) + n_line
    us = torch.as_tensor(rng.uniform(-1, 1, (3, n_step, 4)), dtype=torch.float32)
    z0 = torch.as_tensor(rng.uniform(-1, 1, (3, n_command + n_rest, 4)), dtype=torch.float32)
    out = command_rows_seq(z0, us, b, n_command)
    assert out.shape == (3, n_step, n_command + n_rest, 4)
    z = z0
    for k in range(n_step):
        z = command_rows_step(z, us[:, k], b, n_command)
        assert torch.equal(out[:, k], z)


def test_encode_with_play_matches_numpy_and_widens_the_input(spec, episodes):
    norm = Normalization.fit([e.theta for e in episodes], [e.u for e in episodes], spec, play=PLAY)
    assert norm.n_feature == spec.n_feature + len(PLAY) * spec.n_joint
    ep = episodes[1]
    z = norm.play_from_rest_np(ep.u, spec)
    x_np = norm.encode_np(ep.theta, ep.u, spec, z)
    u_t = torch.as_tensor(ep.u[None], dtype=torch.float32)
    z_t = norm.play_seq(norm.play_rest(1), u_t)
    x_t = norm.encode(torch.as_tensor(ep.theta[None], dtype=torch.float32), u_t, z_t)
    np.testing.assert_allclose(x_t[0].numpy(), x_np, atol=1e-4)
    raw = encode_np(ep.theta, ep.u, spec, play=norm.play_widths, z=z)
    assert np.abs(raw[:, spec.n_feature :]).max() <= 1 + 1e-9  # play features in [-1, 1]
    with pytest.raises(ValueError, match="play"):
        norm.encode(torch.zeros(spec.n_joint), torch.zeros(spec.n_joint))
    # without play widths the layout is the paper's
    plain = Normalization.fit([e.theta for e in episodes], [e.u for e in episodes], spec)
    assert plain.n_feature == spec.n_feature and plain.n_play == 0
    us = scale_commands_np(ep.u, spec)
    np.testing.assert_allclose(raw[:, spec.n_feature - spec.n_joint : spec.n_feature], us)


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_batched_rollout_with_play_equals_the_plain_loop(spec, episodes, mode):
    sur = make_surrogate(spec, episodes, mode=mode, window=5, play=PLAY)
    n = 60
    theta = np.stack([e.theta[:n] for e in episodes])
    u = np.stack([e.u[:n] for e in episodes])
    th_b, om_b = rollout(sur, theta, u)
    for i in range(len(episodes)):
        th_r, om_r = rollout_reference(sur, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-4)
    # the play features reach the network: other widths give another free run
    other = make_surrogate(spec, episodes, mode=mode, window=5, play=(0.01, 0.5))
    assert np.abs(rollout(other, theta, u)[0] - th_b).max() > 1e-4


def test_training_rollout_with_play_equals_the_closed_loop(spec, episodes):
    sur = make_surrogate(spec, episodes, mode="windowed", window=5, play=PLAY)
    ep = episodes[0]
    w, h, t = sur.window, 30, 12
    z = torch.as_tensor(sur.norm.play_from_rest_np(ep.u, spec), dtype=torch.float32)
    f32 = torch.float32
    x = sur.norm.encode(
        torch.as_tensor(ep.theta[t - w + 1 : t + 1], dtype=f32),
        torch.as_tensor(ep.u[t - w + 1 : t + 1], dtype=f32),
        z[t - w + 1 : t + 1],
    )
    with torch.no_grad():
        _, th = window_rollout(
            sur.net,
            sur.norm,
            x[None],
            torch.as_tensor(ep.theta[t], dtype=f32)[None],
            torch.as_tensor(ep.u[t + 1 : t + h], dtype=f32)[None],
            z_next=z[None, t + 1 : t + h],
            n_horizon=h,
            dt=spec.dt,
        )
    # the closed loop warmed up from rest at sample 0 carries the same play states
    th_ref, _ = rollout(sur, ep.theta[None, : t + 1], ep.u[None, : t + h], warmup=t + 1)
    np.testing.assert_allclose(th[0, : h - 1].numpy(), th_ref[0, t + 1 :], atol=1e-5)


def test_checkpoint_keeps_play_widths_and_old_checkpoints_have_none(spec, episodes, tmp_path: Path):
    sur = make_surrogate(spec, episodes, play=PLAY)
    back = load_checkpoint(save_checkpoint(tmp_path / "a.pt", sur))
    assert back.norm.play_widths == pytest.approx(PLAY)
    plain = make_surrogate(spec, episodes)
    old = checkpoint_dict(plain)
    del old["norm"]["play"]  # written before play features existed
    torch.save(old, tmp_path / "old.pt")
    assert load_checkpoint(tmp_path / "old.pt").norm.n_play == 0


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_training_with_play_features(tmp_path, mode):
    ds, sur = train_tiny_free_run(tmp_path, mode, play=PLAY)
    assert sur.norm.play_widths == pytest.approx(PLAY)
    assert sur.model_cfg.n_feature == ds.spec.n_feature + len(PLAY) * ds.spec.n_joint
    th, _ = rollout(sur, ds.test[0].theta[None], ds.test[0].u[None])
    assert np.isfinite(th).all()
    with pytest.raises(Exception, match="play"):
        TrainConfig(play=(0.0,))
