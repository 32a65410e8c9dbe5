"""A merged ensemble stepped member by member equals the merged network and its members."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate import blocks, free_run_error, rollout, rollout_reference
from excavator_surrogate.surrogate.blocks import BlockNet, split
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.rollout import rollout_episodes
from excavator_surrogate.surrogate.uncertainty import member_runs
from excavator_surrogate.surrogate.validation import score_runs
from tests.helpers.surrogates import on_parallel_map, on_static_map, tiny_surrogate

CASES = {
    "plain": dict(end_stops=True, drive=6.0),
    "velocity": dict(end_stops=True, drive=6.0, play=(0.05, 0.2), omega_in=True, residual=True),
    "prior": dict(end_stops=True, prior=True),
}


@pytest.fixture
def any_width(monkeypatch):
    """Split the tests' narrow ensembles too (the rule is tested on its own)."""
    monkeypatch.setattr(blocks, "MIN_SPLIT_WIDTH", 0)


def _members(n_member: int = 3, hidden: int = 12, **kw):
    return [tiny_surrogate(EXCAVATOR, seed=s, hidden=hidden, **kw) for s in range(n_member)]


def _drive(n_batch: int = 2, n_step: int = 70, seed: int = 0):
    """Recorded angles and commands ``(n_batch, n_step, n_joint)`` of a random drive."""
    rng = np.random.default_rng(seed)
    theta = np.cumsum(rng.normal(scale=0.01, size=(n_batch, n_step, 4)), axis=1)
    u = rng.uniform(-900, 900, size=(n_batch, n_step, 4))
    return theta, u


def _same_run(a, b, seed: int = 0) -> np.ndarray:
    """The free runs of ``a`` and ``b`` agree to float32 rounding; returns ``a``'s angles."""
    theta, u = _drive(seed=seed)
    th_a, om_a = rollout(a, theta, u)
    th_b, om_b = rollout(b, theta, u)
    np.testing.assert_allclose(th_a, th_b, atol=1e-6, rtol=1e-6)
    np.testing.assert_allclose(om_a, om_b, atol=1e-5, equal_nan=True)
    return th_a


@pytest.mark.usefixtures("any_width")
@pytest.mark.parametrize("case", list(CASES))
def test_blocks_equal_the_merged_network_and_the_members_averaged(case: str) -> None:
    members = _members(**CASES[case])
    ens = merge(members)
    split_ens = split(ens)
    assert isinstance(split_ens.net, BlockNet) and split_ens.net.n_member == 3
    theta, u = _drive()
    # the merged network runs its own cells when its blocks are not split
    whole = rollout(replace(ens, metrics=None), theta, u)
    th_b, om_b = rollout(split_ens, theta, u)
    np.testing.assert_allclose(th_b, whole[0], atol=1e-6, rtol=1e-6)
    np.testing.assert_allclose(om_b, whole[1], atol=1e-5, equal_nan=True)
    for i in range(len(theta)):  # the plain loop: each member stepped alone, omega averaged
        th_r, om_r = rollout_reference(members, theta[i], u[i])
        np.testing.assert_allclose(th_b[i], th_r, atol=1e-5, rtol=1e-6)
        np.testing.assert_allclose(om_b[i], om_r, atol=1e-4)
    # the test can fail: one member alone runs elsewhere
    assert np.abs(rollout(members[0], theta, u)[0] - th_b).max() > 1e-4


def test_one_step_equals_the_merged_step_from_any_state() -> None:
    ens = merge(_members(n_member=4, hidden=10, omega_in=True, residual=True))
    block = BlockNet.of(ens.net)
    assert block is not None
    gen = torch.Generator().manual_seed(0)
    x = torch.randn(5, ens.model_cfg.n_feature, generator=gen)
    h, c = (torch.randn(2, 5, 40, generator=gen) for _ in range(2))
    mm = (h.reshape(2, 5, 4, 10).transpose(1, 2), c.reshape(2, 5, 4, 10).transpose(1, 2))
    with torch.no_grad():
        y_m, (h_m, c_m) = ens.net.step(x, (h, c))
        y_b, (h_b, c_b) = block.step(x, mm)
    torch.testing.assert_close(y_b, y_m, atol=1e-5, rtol=1e-5)
    for got, want in ((h_b, h_m), (c_b, c_m)):  # member-major (n_layer, M, n, h)
        torch.testing.assert_close(got.transpose(1, 2).reshape(2, 5, 40), want)
    # a member's state moves nothing of another's: member 1's move leaves member 0's
    h2 = mm[0].clone()
    h2[:, 1] += 1.0
    with torch.no_grad():
        _, (h_b2, _) = block.step(x, (h2, mm[1]))
    torch.testing.assert_close(h_b2[:, 0], h_b[:, 0], atol=0, rtol=0)
    assert not torch.allclose(h_b2[:, 1], h_b[:, 1])


@pytest.mark.usefixtures("any_width")
@pytest.mark.parametrize("on_map", [on_static_map, on_parallel_map], ids=["series", "parallel"])
def test_blocks_of_an_ensemble_with_joints_on_a_map(on_map) -> None:
    ens = on_map(merge(_members(end_stops=True, drive=6.0)), delay=(2, 0, 0, 0))
    assert isinstance(split(ens).net, BlockNet)
    _same_run(split(ens), replace(ens, metrics=None), seed=1)


@pytest.mark.usefixtures("any_width")
def test_a_merge_of_composites_splits_into_its_finest_blocks() -> None:
    """The kind choice's model: an ensemble of composites, each of two networks weighted on
    two joints and a third one on the others (its merge record: two members of 36 units)."""
    nets = _members(n_member=6, end_stops=True, drive=6.0)
    groups = [
        merge(nets[3 * g : 3 * g + 3], joint_weights=[[0.5, 0.5, 0, 0]] * 2 + [[0, 0, 1, 1]])
        for g in range(2)
    ]
    ens = merge(groups)
    assert split(ens).net.n_member == 6
    comp = merge(nets[:2], joint_weights=[[1, 0, 1, 0], [0, 1, 0, 1]])
    assert split(comp).net.n_member == 2
    for model in (ens, comp):
        _same_run(split(model), replace(model, metrics=None), seed=2)


@pytest.mark.usefixtures("any_width")
def test_what_does_not_split_is_returned_as_it_is() -> None:
    single = tiny_surrogate(EXCAVATOR, seed=0)
    gru = merge([tiny_surrogate(EXCAVATOR, seed=s, cell="gru") for s in range(2)])
    windowed = merge([tiny_surrogate(EXCAVATOR, seed=s, mode="windowed") for s in range(2)])
    widths = merge([tiny_surrogate(EXCAVATOR, seed=s, hidden=8 + s) for s in range(2)])
    tuned = merge(_members(n_member=2))
    with torch.no_grad():  # trained on after the merge: member 1's state feeds member 0
        tuned.net.rnn.weight_hh_l1[0, 15] = 0.1
    mixed_head = merge(_members(n_member=2))
    with torch.no_grad():
        mixed_head.net.head[0].weight[0, 20] = 0.1
    for sur in (single, gru, windowed, widths, tuned, mixed_head):
        assert split(sur) is sur
    assert BlockNet.of(windowed.net) is not None  # an ensemble of equal blocks, run windowed
    # the blocks are found in the weights: a record without the members' widths splits too
    bare = replace(merge(_members(n_member=2)), metrics={"ensemble": {"n_member": 2}})
    assert isinstance(split(bare).net, BlockNet)
    # ... and a network without a merge record is not searched for blocks
    assert split(replace(bare, metrics=None)).net is bare.net


def test_narrow_ensembles_run_merged() -> None:
    assert blocks.MIN_SPLIT_WIDTH == 256
    narrow = merge(_members(n_member=3, hidden=64))
    assert split(narrow) is narrow
    wide = merge(_members(n_member=2, hidden=128))
    assert isinstance(split(wide).net, BlockNet)


@pytest.mark.usefixtures("any_width")
def test_validation_free_runs_step_the_blocks(monkeypatch, spec, episodes) -> None:
    ens = merge([tiny_surrogate(spec, episodes, seed=s, end_stops=True) for s in range(3)])
    runs = rollout_episodes(replace(ens, metrics=None), episodes, max_steps=60)
    want = score_runs(runs, ens)
    got = free_run_error(ens, episodes, max_steps=60)
    np.testing.assert_allclose(got["theta_rmse"], want["theta_rmse"], rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(got["val_error"], want["val_error"], rtol=1e-4)
    calls = []
    step = BlockNet.step

    def counted(self, x_t, state):
        calls.append(1)
        return step(self, x_t, state)

    monkeypatch.setattr(BlockNet, "step", counted)
    free_run_error(ens, episodes, max_steps=60)
    assert calls  # the validation free run went through the member blocks


@pytest.mark.parametrize("design", ["shared", "independent"])
def test_member_runs_through_the_blocks_equal_the_merged_networks(monkeypatch, design) -> None:
    """The calibration's free runs report each member (a hook on the head's ReLU): the
    blocks give the same members' velocities as the merged network, rows following members
    included."""
    ens = on_parallel_map(merge(_members(end_stops=True, drive=6.0)), delay=(2, 0, 0, 0))
    theta, u = _drive(seed=4)
    monkeypatch.setattr(blocks, "MIN_SPLIT_WIDTH", 10**9)  # the merged network's cells
    want = member_runs(ens, theta, u, design=design)
    monkeypatch.setattr(blocks, "MIN_SPLIT_WIDTH", 0)
    calls = []
    step = BlockNet.step
    monkeypatch.setattr(BlockNet, "step", lambda *a: calls.append(1) or step(*a))
    got = member_runs(ens, theta, u, design=design)
    assert calls
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, atol=1e-5, rtol=1e-6, equal_nan=True)
    # the test can fail: the members run apart
    assert np.nanmax(np.abs(want[3][0] - want[3][1])) > 1e-3
