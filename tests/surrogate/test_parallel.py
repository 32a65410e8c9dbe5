"""Joints on a static map in parallel: the network keeps its own free run, the map joints
follow the map's own free run; the checkpoint keeps both; members spread on the map joints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.checkpoint import (
    checkpoint_dict,
    load_checkpoint,
    save_checkpoint,
    write_checkpoint_dict,
)
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.parallel import own_gain_dev, with_parallel_map
from excavator_surrogate.surrogate.reference import rollout_reference
from excavator_surrogate.surrogate.rollout import ClosedLoop, rollout
from excavator_surrogate.surrogate.uncertainty import map_note
from tests.helpers.surrogates import (
    PARALLEL_JOINTS,
    map_fit,
    on_parallel_map,
    tight_stops,
    tiny_surrogate,
)

PICK = np.array(PARALLEL_JOINTS)


def _drive(n_step: int = 70, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Recorded angles (1, n_step, 4) [rad] and commands (1, n_step, 4) that cross the map's
    dead zone both ways."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_step) * EXCAVATOR.dt
    u = 600.0 * np.sin(2 * np.pi * np.array([0.3, 0.5, 0.7, 0.4]) * t[:, None] + rng.random(4))
    theta = np.cumsum(rng.normal(0, 0.01, (n_step, 4)), axis=0) + np.array([0, 0, 1.5, 0.5])
    return theta[None], u[None]


@pytest.mark.parametrize(
    ("mode", "kw", "delay"),
    [
        ("stateful", {}, None),
        ("stateful", {"play": (0.05,), "omega_in": True, "residual": True}, (2, 0, 0, 3)),
        ("windowed", {"end_stops": True, "drive": 20.0}, (1, 0, 0, 0)),
        ("stateful", {"end_stops": True, "drive": 20.0, "prior": True}, (2, 0, 0, 0)),
    ],
)
def test_each_joint_runs_as_its_source_alone(mode: str, kw: dict, delay) -> None:
    """The other joints' free run is the network's own free run (it reads its own angles of
    the map joints); the map joints' is the map's own (a NumPy loop); the batched loop
    equals the plain loop."""
    net = tiny_surrogate(EXCAVATOR, mode=mode, seed=4, **kw)
    par = on_parallel_map(net, delay=delay)
    assert par.norm.own is not None and par.norm.n_own == 2
    assert par.metrics["map_joints"] == ["swing", "bucket"] and par.metrics["map_parallel"]
    theta, u = _drive()
    th, om = rollout(par, theta, u)
    th_net, om_net = rollout(net, theta, u)
    w = net.window
    np.testing.assert_allclose(th[0][:, ~PICK], th_net[0][:, ~PICK], atol=2e-5)
    np.testing.assert_allclose(om[0, w:][:, ~PICK], om_net[0, w:][:, ~PICK], atol=2e-4)
    th_ref, om_ref = rollout_reference(par, theta[0], u[0])
    np.testing.assert_allclose(th[0], th_ref, atol=2e-5)
    np.testing.assert_allclose(om[0, w:], om_ref[w:], atol=2e-4)
    # the map joints move: the map is not a constant
    assert np.ptp(th[0, w:, 0]) > 1e-3 and np.ptp(th[0, w:, 3]) > 1e-3


def test_map_joints_stop_at_their_own_end_stops_and_the_network_at_its(tmp_path: Path) -> None:
    """With tighter end stops on the map joints (the structured model's), the map joints stop
    there, the network still runs its own free run within its own end stops (the other joints
    are exactly the network's alone), the plain loop agrees, and the checkpoint keeps both."""
    net = tiny_surrogate(EXCAVATOR, seed=4, end_stops=True, drive=20.0)
    par = on_parallel_map(net, delay=(2, 0, 0, 0), stops=True)
    lo, hi = tight_stops(EXCAVATOR)
    own = par.norm.own
    assert own is not None and own.theta_min is not None and own.theta_max is not None
    np.testing.assert_allclose(own.theta_min.numpy()[1:], net.limits_np()[0][1:])
    assert par.spec.joints[3].theta_max == pytest.approx(hi[3])  # the bucket: the map's stops
    assert par.spec.joints[1].theta_max == net.spec.joints[1].theta_max  # the boom: the network's
    theta, u = _drive(n_step=120, seed=3)
    u[0, :, 3] = 900.0  # the map drives the bucket up into its stop; the network drives it down
    th, om = rollout(par, theta, u)
    th_net, _ = rollout(net, theta, u)
    np.testing.assert_allclose(th[0][:, ~PICK], th_net[0][:, ~PICK], atol=2e-5)
    w = net.window
    assert th[0, w:, 3].max() == pytest.approx(hi[3], abs=1e-6)
    assert th_net[0, w:, 3].min() < lo[3]  # the network's own bucket goes past the map's stop
    th_ref, om_ref = rollout_reference(par, theta[0], u[0])
    np.testing.assert_allclose(th[0], th_ref, atol=2e-5)
    np.testing.assert_allclose(om[0, w:], om_ref[w:], atol=2e-4)
    back = load_checkpoint(save_checkpoint(tmp_path / "m.pt", par))
    assert back.norm.own is not None and back.norm.own.theta_min is not None
    np.testing.assert_allclose(rollout(back, theta, u)[0], th, atol=1e-6)
    old = checkpoint_dict(par)  # a checkpoint from before the own end stops were kept
    del old["norm"]["own_theta_min"], old["norm"]["own_theta_max"]
    write_checkpoint_dict(tmp_path / "old.pt", old)
    assert load_checkpoint(tmp_path / "old.pt").norm.own.theta_min is None


def test_the_map_joints_follow_the_map_whatever_the_network_does() -> None:
    """Two different networks with the same map joints give the same map-joint angles."""
    theta, u = _drive(seed=1)
    a = on_parallel_map(tiny_surrogate(EXCAVATOR, seed=1), delay=(2, 0, 0, 1))
    b = on_parallel_map(tiny_surrogate(EXCAVATOR, seed=2), delay=(2, 0, 0, 1))
    th_a, _ = rollout(a, theta, u)
    th_b, _ = rollout(b, theta, u)
    np.testing.assert_allclose(th_a[0][:, PICK], th_b[0][:, PICK], atol=1e-5)
    assert not np.allclose(th_a[0][:, ~PICK], th_b[0][:, ~PICK], atol=1e-3)


def test_the_checkpoint_keeps_the_map_and_a_corrupt_one_is_one_clear_error(
    tmp_path: Path,
) -> None:
    par = on_parallel_map(tiny_surrogate(EXCAVATOR, seed=5), delay=(2, 0, 0, 0))
    path = save_checkpoint(tmp_path / "m.pt", par)
    back = load_checkpoint(path)
    assert back.norm.own is not None and back.norm.own.own == tuple(PARALLEL_JOINTS)
    assert back.norm.own.delay == (2, 0, 0, 0) and back.norm.lags == (2, 0, 0, 0)
    theta, u = _drive(seed=2)
    np.testing.assert_allclose(rollout(back, theta, u)[0], rollout(par, theta, u)[0], atol=1e-6)
    bad = checkpoint_dict(par)
    bad["norm"]["own_delay"] = torch.tensor([9.0, 0.0, 0.0, 0.0])  # beyond the delay line
    write_checkpoint_dict(tmp_path / "bad.pt", bad)
    with pytest.raises(CheckpointError, match="delay line"):
        load_checkpoint(tmp_path / "bad.pt")


def test_a_map_delay_beyond_the_networks_line_is_refused() -> None:
    net = tiny_surrogate(EXCAVATOR, seed=6)
    lagged = with_parallel_map(net, map_fit(EXCAVATOR, (1, 0, 0, 0)), PARALLEL_JOINTS)
    assert lagged.norm.lags == (1, 0, 0, 0)
    with pytest.raises(ValueError, match="already has joints"):
        with_parallel_map(lagged, map_fit(EXCAVATOR), PARALLEL_JOINTS)
    with pytest.raises(ValueError, match="delay line"):
        with_parallel_map(
            lagged.__class__(**{**lagged.__dict__, "norm": lagged.norm.with_own(None)}),
            map_fit(EXCAVATOR, (3, 0, 0, 0)),
            PARALLEL_JOINTS,
        )


def test_members_spread_on_the_map_joints_by_the_maps_gain_spread() -> None:
    """A merged ensemble on a map in parallel: member m drives a map joint with gain
    1 + sigma_j z_m; the mean is the map; a row that follows member m integrates it there."""
    members = [tiny_surrogate(EXCAVATOR, seed=s) for s in (7, 8, 9)]
    par = on_parallel_map(merge(members), delay=(2, 0, 0, 0))
    dev = own_gain_dev(par)
    assert dev.shape == (3, 4) and torch.all(dev[:, ~torch.tensor(PICK)] == 0)
    note = map_note(par)
    assert note is not None and "swing, bucket" in note and "gain spread" in note
    np.testing.assert_allclose(dev[:, 0].std().item(), 0.2, rtol=1e-6)
    theta, u = _drive(seed=3)
    w = par.window
    loop = ClosedLoop(par, members=True)
    loop.reset(np.repeat(theta[:, :w], 2, 0), np.repeat(u[:, : w - 1], 2, 0))
    loop.follow = torch.tensor([-1, 2])
    for k in range(w - 1, w + 20):
        _, om = loop.step(torch.tensor(np.repeat(u[:, k], 2, 0)).float())
        om_m = loop.omega_members
        assert om_m is not None
        mean = om[0, PICK].double()
        for m in range(3):
            want = mean * (1.0 + dev[m, PICK])
            torch.testing.assert_close(om_m[m, 0, PICK].double(), want, atol=1e-6, rtol=1e-5)
        torch.testing.assert_close(om[1, PICK], om_m[2, 1, PICK], atol=1e-6, rtol=1e-5)


def test_resuming_training_from_a_parallel_model_is_one_clear_error(tmp_path: Path) -> None:
    """Training runs the network alone: a checkpoint whose joints follow a map beside it
    cannot be resumed (one line naming the file and the joints, and what to do)."""
    from excavator_surrogate.training.resume import start
    from tests.helpers.training import tiny_train_config

    cfg = tiny_train_config(window=6, hidden=16)
    net = tiny_surrogate(EXCAVATOR, seed=10, window=6, hidden=16)
    path = save_checkpoint(tmp_path / "best.pt", on_parallel_map(net, delay=(1, 0, 0, 0)))
    mcfg = cfg.model_config(EXCAVATOR.n_feature, EXCAVATOR.n_joint)
    with pytest.raises(CheckpointError, match=r"best\.pt: joints swing, bucket follow .* last\.pt"):
        start(cfg, mcfg, EXCAVATOR, [], path)
