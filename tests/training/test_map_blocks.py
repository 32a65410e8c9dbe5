"""The map choice on one validation segment: a candidate must hold on both halves."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from excavator_surrogate.surrogate.series import with_map_joints
from excavator_surrogate.surrogate.structured import fit_prior
from excavator_surrogate.surrogate.validation import free_run_error
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.map_blocks import (
    block_scores,
    held_on_blocks,
    validation_blocks,
)
from excavator_surrogate.training.map_joints import choose_map_joints, map_options
from tests.helpers.surrogates import tiny_surrogate
from tests.surrogate.test_prior import _static_episode
from tests.surrogate.test_structured import SPEC


def _net():
    """An untrained network: it barely moves."""
    return tiny_surrogate(SPEC, mode="stateful", window=6, seed=3)


def _faster_from(ep, start: int, gain: float):
    """``ep`` with the plant ``gain`` times as fast from sample ``start`` on (the same
    commands; the angle continues from where it was)."""
    theta = ep.theta.copy()
    theta[start:] = theta[start] + gain * (ep.theta[start:] - ep.theta[start])
    omega = ep.omega.copy()
    omega[start:] *= gain
    return dataclasses.replace(ep, theta=theta, omega=omega)


def test_the_blocks_are_one_validation_episodes_halves() -> None:
    eps = [_static_episode(s) for s in (7, 8)]
    halves, what = validation_blocks(eps[:1], warmup=6)
    assert [b.n_step for b in halves] == [300, 300] and "halves" in what
    np.testing.assert_array_equal(np.concatenate([b.theta for b in halves]), eps[0].theta)
    cut, _ = validation_blocks(eps[:1], warmup=6, max_steps=101)  # halved as it free-runs
    assert [b.n_step for b in cut] == [50, 50]
    np.testing.assert_array_equal(cut[1].u, eps[0].u[50:100])
    short, what = validation_blocks(eps[:1], warmup=6, max_steps=23)  # 11 < 2 x 6
    assert short == [] and "too short" in what
    pooled, what = validation_blocks(eps, warmup=6)  # several episodes: pooled, no blocks
    assert pooled == [] and "pooled" in what
    assert validation_blocks([], warmup=6)[0] == []


def test_a_joint_holds_on_more_than_half_of_the_blocks_within_the_tie() -> None:
    net = [[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]
    on_map = [[1.05, 0.5], [2.0, 2.0], [0.9, 2.0]]  # a: 2 of 3 (one a tie); b: 1 of 3
    assert held_on_blocks(net, on_map, tie=0.05) == [True, False]
    assert held_on_blocks(net, on_map, tie=0.0) == [False, False]  # 1.05 is no longer a tie
    assert held_on_blocks(net[:2], on_map[:2], tie=0.05) == [False, False]  # 2: both must hold


def test_block_scores_equal_each_blocks_own_free_run() -> None:
    """The batched free run over the blocks scores each block as its own free run does."""
    train = [_static_episode(s) for s in range(3)]
    blocks, _ = validation_blocks([_static_episode(7)], warmup=6)
    sur = _net()
    fits = [fit_prior(train, SPEC), fit_prior([_faster_from(train[0], 0, 2.0)], SPEC)]
    net_b, map_b = block_scores(sur, fits, [0, 1], blocks, stops=None)
    for b, block in enumerate(blocks):
        ref = free_run_error(sur, [block])["theta_rmse"]
        np.testing.assert_allclose(net_b[b], ref, rtol=1e-5, atol=1e-8)
        for j, fit in enumerate(fits):
            on = with_map_joints(sur, fit, [True, True])
            want = free_run_error(on, [block])["theta_rmse"][j]
            np.testing.assert_allclose(map_b[b][j], want, rtol=1e-5, atol=1e-8)
    # a variant no joint picks is never run (None would fail to build a map surrogate)
    unused: list = [fits[0], None]
    net_0, map_0 = block_scores(sur, unused, [0, 0], blocks, stops=None)
    assert net_0 == net_b
    for b, block in enumerate(blocks):
        want = free_run_error(with_map_joints(sur, fits[0], [True, True]), [block])
        np.testing.assert_allclose(map_0[b], want["theta_rmse"], rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize("parallel", [False, True])
def test_a_map_that_wins_the_whole_run_on_one_half_only_is_refused(parallel: bool) -> None:
    """One validation episode: the machine of the training split for its first half, 1.5x as
    fast for its second.  A model of the faster machine (the 'network') is off in the first
    half and carries the offset through the second, so the training's map wins the whole
    free run; on the halves, each from its own warm-up, each model wins one.  The map is
    refused; without the check it is chosen."""
    train = [_static_episode(s) for s in range(3)]
    val = [_faster_from(_static_episode(7, n_step=800), 400, 1.5)]
    faster = [_faster_from(_static_episode(s), 0, 1.5) for s in range(3)]
    net = with_map_joints(_net(), fit_prior(faster, SPEC), [True, True])
    options = {"parallel": parallel, "periodic": False}
    on, rec_on = choose_map_joints(net, train, val, blocks=False, **options)
    assert on is not None and rec_on["chosen"] == ["a", "b"] and "blocks" not in rec_on
    whole_net, whole_map = rec_on["val_theta_rmse_network"], rec_on["val_theta_rmse_map"]
    assert all(m < n for m, n in zip(whole_map, whole_net))  # the map wins the whole run
    off, rec = choose_map_joints(net, train, val, **options)
    assert off is None and rec["chosen"] == [] and rec["candidates"] == []
    blocks = rec["blocks"]
    assert blocks["what"] == "the validation episode's halves"
    assert blocks["checked"] == ["a", "b"] and blocks["refused"] == ["a", "b"]
    (net_1, net_2), (map_1, map_2) = blocks["val_theta_rmse_network"], blocks["val_theta_rmse_map"]
    assert all(m < n for m, n in zip(map_1, net_1)) and all(m > n for m, n in zip(map_2, net_2))
    assert "not on both of the validation episode's halves" in rec["why"]


def test_a_map_that_holds_on_both_halves_is_chosen_and_episodes_are_not_checked() -> None:
    """Where the map is the machine, it holds on both halves and is chosen as before; several
    validation episodes are not checked (the pooled run decides); in parallel a joint the map
    runs with R^2 >= 0.95 is pinned, not checked."""
    train = [_static_episode(s) for s in range(3)]
    one = [_static_episode(7)]
    new, rec = choose_map_joints(_net(), train, one)
    assert new is not None and rec["chosen"] == ["a", "b"]
    assert rec["blocks"]["what"] == "the validation episode's halves"
    assert rec["blocks"]["checked"] == ["a", "b"] and rec["blocks"]["refused"] == []
    two = [_static_episode(s) for s in (7, 8)]
    new2, rec2 = choose_map_joints(_net(), train, two)
    assert new2 is not None and rec2["chosen"] == ["a", "b"] and "blocks" not in rec2
    pinned, rec_p = choose_map_joints(_net(), train, one, **map_options(TrainConfig()))
    assert pinned is not None and rec_p["pinned"] == ["a", "b"] and "blocks" not in rec_p


def test_the_option_reaches_the_choice() -> None:
    assert map_options(TrainConfig())["blocks"] is True
    assert map_options(TrainConfig(map_blocks=False))["blocks"] is False
