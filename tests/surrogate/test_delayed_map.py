"""A static map with a delay: the delayed-command features, their delay line, the map chosen
on a delayed plant, its free run against a plain loop, its checkpoint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.features import scale_commands_np
from excavator_surrogate.surrogate.model import Surrogate
from excavator_surrogate.surrogate.reference import rollout_reference
from excavator_surrogate.surrogate.rollout import rollout
from excavator_surrogate.surrogate.series import with_map_joints
from excavator_surrogate.surrogate.structured import fit_prior
from excavator_surrogate.training.api import train
from excavator_surrogate.training.batches import make_data
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.map_joints import choose_map_joints
from excavator_surrogate.training.modes import make_mode
from excavator_surrogate.training.resume import start
from tests.helpers.surrogates import free_run_checked, on_static_map, tiny_surrogate
from tests.helpers.training import tiny_train_config
from tests.surrogate.test_structured import SPEC, TRUTH, _episode

LAGS = (2, 0, 3, 1)


def test_delay_line_features_equal_the_numpy_reference() -> None:
    """Stepped in torch (play operators and the delay line in one state ``z``), the features
    equal the NumPy encoding from rest, and each delayed column is ``us_j[k - d_j]`` (0
    before the first sample)."""
    sur = tiny_surrogate(EXCAVATOR, play=(0.1,), omega_in=True)
    norm = sur.norm.with_lags(LAGS)
    assert norm.n_line == 4 and norm.n_state == 5 and norm.n_feature == sur.norm.n_feature + 4
    rng = np.random.default_rng(0)
    n_step = 12
    u = rng.uniform(-1000, 1000, (2, n_step, 4))
    theta = rng.uniform(-1, 1, (2, n_step, 4))
    omega = rng.uniform(-1, 1, (2, n_step, 4))
    z = norm.play_rest(2)
    rows = []
    for k in range(n_step):
        z = norm.play_update(z, torch.tensor(u[:, k]).float())
        rows.append(
            norm.encode(
                torch.tensor(theta[:, k]).float(),
                torch.tensor(u[:, k]).float(),
                z,
                torch.tensor(omega[:, k]).float(),
            )
        )
    x = torch.stack(rows, 1).double().numpy()
    zs = norm.play_from_rest_np(u, EXCAVATOR)
    assert zs.shape == (2, n_step, 5, 4)
    ref = norm.encode_np(theta, u, EXCAVATOR, zs, omega)
    np.testing.assert_allclose(x, ref, atol=1e-5)
    # the delayed columns (before the 4 velocity columns), un-normalised
    at = sur.norm.n_feature - 4
    lag = (
        ref[..., at : at + 4] * norm.x_std[at : at + 4].double().numpy()
        + norm.x_mean[at : at + 4].double().numpy()
    )
    us = scale_commands_np(u, EXCAVATOR)
    for j, d in enumerate(LAGS):
        want = np.concatenate([np.zeros((2, d)), us[:, : n_step - d, j]], axis=1)
        np.testing.assert_allclose(lag[..., j], want, atol=1e-6)
    with pytest.raises(ValueError, match="one delay >= 0 per joint"):
        sur.norm.with_lags((1, 2))


def _net():
    """An untrained 2-joint network (W = 6: delays up to 5 samples)."""
    return tiny_surrogate(SPEC, mode="stateful", window=6, seed=3)


def test_a_delayed_plant_gets_its_delays_and_its_free_run_equals_a_plain_loop(
    tmp_path: Path,
) -> None:
    """On test_structured's dead-zone / gain / delay plant (delays 3 and 5), the map choice
    fits the delays, prefers them to the undelayed map on validation and then drives the
    plant exactly; the free run equals the plain loop, and the checkpoint keeps it."""
    train = [_episode(s) for s in range(3)]
    val = [_episode(s) for s in (7, 8)]
    new, rec = choose_map_joints(_net(), train, val)
    assert new is not None and rec["chosen"] == list(SPEC.names)
    assert rec["map"]["delay"] == [f.delay for f in TRUTH] == rec["fitted_delay"]
    maps = rec["val_theta_rmse_maps"]
    assert all(a < 0.1 * b for a, b in zip(maps["delayed"], maps["undelayed"]))
    assert new.metrics["val_error"] < 1e-3 and new.norm.lags == (3, 5)
    ep = _episode(9)
    theta, u = ep.theta[None, :80], ep.u[None, :80]
    th, om = rollout(new, theta, u)
    th_ref, om_ref = rollout_reference(new, theta[0], u[0])
    np.testing.assert_allclose(th[0], th_ref, atol=1e-5)
    w = new.window
    np.testing.assert_allclose(om[0, w:], om_ref[w:], atol=1e-5)
    # omega[k+1] = s(u[k - d]): the plant's own speeds
    np.testing.assert_allclose(om[0, w:], ep.omega[w:80], atol=1e-5)
    path = save_checkpoint(tmp_path / "m.pt", new)
    back = load_checkpoint(path)
    assert back.norm.lags == (3, 5) and back.net.prior is not None
    th2, _ = rollout(back, theta, u)
    np.testing.assert_allclose(th2, th, atol=1e-6)


def test_other_joints_keep_the_networks_output(spec, episodes) -> None:
    """Joint 0 on a delayed map: the network's first layer reads the new columns with zero
    weights, so the other joints' output on the same samples is the network's."""
    sur = tiny_surrogate(spec, episodes, mode="stateful", hidden=12)
    fit = fit_prior(episodes, spec)
    n = spec.n_joint
    fit["delay"] = [3] + [0] * (n - 1)
    hyb = with_map_joints(sur, fit, [True] + [False] * (n - 1))
    assert hyb.norm.lags == (3,) + (0,) * (n - 1)
    ep = episodes[0]
    th, u = torch.tensor(ep.theta[:40]).float(), torch.tensor(ep.u[:40]).float()
    x0 = sur.norm.encode(th, u)
    z = hyb.norm.play_seq(hyb.norm.play_rest(1), u[None])[0]
    x1 = hyb.norm.encode(th, u, z)
    with torch.no_grad():
        y0, _ = sur.net.forward_seq(x0[None])
        y1, _ = hyb.net.forward_seq(x1[None])
    om0, om1 = sur.norm.omega(y0)[0], hyb.norm.omega(y1)[0]
    torch.testing.assert_close(om1[:, 1:], om0[:, 1:], atol=1e-5, rtol=0)
    s = hyb.net.prior.speed(u[:, :n])
    torch.testing.assert_close(om1[3:, 0], s[:-3, 0], atol=1e-5, rtol=0)


def test_a_checkpoint_with_bad_delays_is_one_clear_error(tmp_path: Path) -> None:
    fit = fit_prior([_episode(s) for s in range(2)], SPEC, max_delay=5)
    new = with_map_joints(_net(), fit, [True, True])
    path = save_checkpoint(tmp_path / "m.pt", new)
    ck = torch.load(path, weights_only=True)
    ck["norm"]["lags"] = torch.tensor([1.0, -2.0])
    torch.save(ck, path)
    with pytest.raises(CheckpointError, match="normalisation entry is malformed"):
        load_checkpoint(path)


def test_training_with_a_speed_prior_starts(spec, episodes) -> None:
    """``[train] prior = true`` fits the map and loads only its buffers (the fit's extra
    entries, e.g. its gain spread, are not the prior's)."""
    cfg = TrainConfig(prior=True)
    st = start(cfg, cfg.model_config(spec.n_feature, spec.n_joint), spec, list(episodes), None)
    assert st.net.prior is not None and float(st.net.prior.k_pos.abs().sum()) > 0
    assert any("speed prior dead zone" in line for line in st.derived)


@pytest.mark.parametrize(
    ("mode", "feedback"), [("stateful", "teacher"), ("stateful", "free"), ("windowed", "teacher")]
)
def test_a_speed_prior_is_trained_with_its_delay(mode: str, feedback: str) -> None:
    """``prior = true`` on the dead-zone / gain / delay plant (delays 3 and 5): the prior
    takes the fitted delays, the network's first layer reads the delayed commands, and with a
    silent head every training mode's predictions are the plant's speeds (the batches carry
    the delay line like every runtime)."""
    train_eps = [_episode(s) for s in range(3)]
    cfg = tiny_train_config(
        prior=True, mode=mode, window=6, burn_in=6, feedback=feedback, teacher_epochs=0, horizon=4
    )
    st = start(cfg, cfg.model_config(SPEC.n_feature, SPEC.n_joint), SPEC, train_eps, None)
    assert st.norm.lags == (3, 5)
    assert st.model_cfg.n_feature == st.norm.n_feature == SPEC.n_feature + SPEC.n_joint
    assert st.net.rnn.weight_ih_l0.shape[1] == st.norm.n_feature
    assert st.net.prior.cols.tolist() == [st.norm.lag_start, st.norm.lag_start + 1]
    assert any("delay 0.15 s" in line for line in st.derived)  # 3 samples at 20 Hz
    with torch.no_grad():  # a silent head: the network is the delayed map
        st.net.head[2].weight.zero_()
        st.net.head[2].bias.zero_()
    sur = Surrogate(
        net=st.net,
        spec=st.spec,
        norm=st.norm,
        model_cfg=st.model_cfg,
        mode=mode,
        train_config={},
        metrics={},
        name="lstm",
        end_stops=False,
    )
    mode_ = make_mode(cfg, make_data(train_eps, st.norm, torch.device("cpu")), sur)
    batch = mode_.batches(np.random.default_rng(0), 1)[0]
    with torch.no_grad():
        for y_hat, y, _ in mode_.predict(st.net, batch, epoch=1):
            torch.testing.assert_close(y_hat, y, atol=1e-4, rtol=0)


def test_a_delayed_prior_trains_resumes_and_runs_like_a_plain_loop(tmp_path: Path) -> None:
    """A short run with the delayed prior: ``best.pt`` keeps the delays, its free run equals
    the plain loop, and a resumed run accepts its wider first layer."""
    ds = Dataset(spec=SPEC)
    ds.episodes["train"] = [_episode(s) for s in range(3)]
    ds.episodes["val"] = [_episode(7)]
    kw = dict(prior=True, window=6, burn_in=6, max_train_seconds=0.0)
    best = train(tiny_train_config(epochs=2, **kw), ds, out=tmp_path / "a", show_progress=False)
    sur = load_checkpoint(best)
    assert sur.norm.lags == (3, 5) and sur.net.prior is not None
    free_run_checked(sur, _episode(9), 60)
    train(
        tiny_train_config(epochs=3, **kw),
        ds,
        out=tmp_path / "a",
        resume=tmp_path / "a" / "last.pt",
        show_progress=False,
    )
    assert load_checkpoint(tmp_path / "a" / "last.pt").norm.lags == (3, 5)


def test_members_with_other_delays_are_not_merged() -> None:
    a = on_static_map(tiny_surrogate(seed=0), delay=(2, 0, 0, 0))
    b = on_static_map(tiny_surrogate(seed=1), delay=(1, 0, 0, 0))
    with pytest.raises(ConfigError, match="command delays"):
        merge([a, b])
    c = on_static_map(tiny_surrogate(seed=1), delay=(2, 0, 0, 0))
    merged = merge([a, c])
    assert merged.norm.lags == (2, 0, 0, 0)
    # the merged network's free run is the members' mean, each stepped on its own
    rng = np.random.default_rng(4)
    u = rng.uniform(-1000, 1000, (30, 4))
    theta = np.repeat(np.array([[0.1, 0.2, 1.5, 0.5]]), 30, axis=0)
    th, _ = rollout(merged, theta[None], u[None])
    th_ref, _ = rollout_reference([a, c], theta, u)
    np.testing.assert_allclose(th[0], th_ref, atol=1e-5)
