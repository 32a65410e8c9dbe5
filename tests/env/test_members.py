"""The per-member kernel of merged LSTM ensembles against the dense kernels and the plain loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.env.kernels import MEMBERS_MIN_BATCH
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.reference import rollout_reference
from tests.helpers.surrogates import on_parallel_map, on_static_map

KW = dict(mode="stateful", end_stops=True, drive=20.0, play=(0.05, 0.2), omega_in=True)


@pytest.fixture(scope="module")
def members(make_surrogate):
    return [make_surrogate(seed=s, hidden=16, **KW) for s in range(3)]


@pytest.mark.parametrize(
    "delayed_map", [False, True, "parallel"], ids=["network", "delayed-map", "parallel-map"]
)
def test_members_kernel_equals_plain_loop_and_dense_kernels(members, delayed_map) -> None:
    """Three members stepped as one batched matmul equal the members stepped one by one with
    their omega averaged (the plain loop), and the dense cell and module kernels; masked
    resets and a fork from a dense one-env engine keep them equal (also with the swing and
    the bucket on a static map with delays 2 and 1, in series or in parallel: the fork
    carries the delay line and the network's own angles)."""
    ens = merge(members)
    ref = members
    if delayed_map == "parallel":
        ens = ref = on_parallel_map(ens, delay=(2, 0, 0, 1))
        assert ens.norm.lags == (2, 0, 0, 1) and ens.norm.n_own == 2
    elif delayed_map:
        ens = ref = on_static_map(ens, delay=(2, 0, 0, 1))
        assert ens.norm.lags == (2, 0, 0, 1)
    rng = np.random.default_rng(5)
    n, w, n_cmd = 4, members[0].window, 30
    theta0 = rng.uniform(-0.3, 0.3, (n, 4)) + np.array([0.0, 0.0, 1.5, 0.5])
    u = rng.uniform(-1000, 1000, (n, n_cmd, 4))
    engines = {k: SurrogateEngine(ens, n_envs=n, impl=k) for k in ("members", "cell", "module")}
    assert engines["members"].impl == "members" and engines["members"].h.shape == (2, 3, n, 16)
    out = {}
    for k, eng in engines.items():
        eng.reset(theta0)
        out[k] = np.stack([eng.step(u[:, j])[0].numpy().copy() for j in range(n_cmd)], axis=1)
    for i in range(n):
        u_ref = np.concatenate([np.zeros((w - 1, 4)), u[i], np.zeros((1, 4))])
        th_ref, _ = rollout_reference(ref, np.repeat(theta0[i][None], w, 0), u_ref)
        np.testing.assert_allclose(out["members"][i], th_ref[w:], atol=1e-5)
    for k in ("cell", "module"):
        np.testing.assert_allclose(out["members"], out[k], atol=1e-5)
    # a masked reset, then a fork of env 2 of a dense engine into every env
    mask = np.array([True, False, True, False])
    for eng in engines.values():
        eng.reset(theta0[::-1].copy(), mask)
    steps = {k: eng.step(u[:, 0])[0].numpy().copy() for k, eng in engines.items()}
    np.testing.assert_allclose(steps["members"], steps["cell"], atol=1e-5)
    for eng in engines.values():
        eng.fork(engines["cell"], row=2)
    steps = {k: eng.step(u[:, 1])[0].numpy().copy() for k, eng in engines.items()}
    np.testing.assert_allclose(steps["members"], steps["cell"], atol=1e-5)
    h_m, c_m = engines["members"].dense_state()
    h_c, c_c = engines["cell"].dense_state()
    torch.testing.assert_close(h_m, h_c, atol=1e-5, rtol=0)
    torch.testing.assert_close(c_m, c_c, atol=1e-5, rtol=0)


def test_auto_picks_the_member_kernel_from_its_batch_size(members, make_surrogate) -> None:
    ens = merge(members)
    assert SurrogateEngine(ens, n_envs=MEMBERS_MIN_BATCH).impl == "members"
    assert SurrogateEngine(ens, n_envs=MEMBERS_MIN_BATCH - 1).impl == "cell"
    single = make_surrogate(seed=0, hidden=16, **KW)
    assert SurrogateEngine(single, n_envs=MEMBERS_MIN_BATCH).impl == "cell"
    with pytest.raises(ConfigError, match="impl='members' needs a merged LSTM seed ensemble"):
        SurrogateEngine(single, n_envs=4, impl="members")
    # members of different widths, and GRU ensembles, stay on the dense kernels
    mixed = merge([members[0], make_surrogate(seed=1, hidden=8, **KW)])
    assert SurrogateEngine(mixed, n_envs=MEMBERS_MIN_BATCH).impl == "cell"
    gru = merge([make_surrogate(seed=s, hidden=8, cell="gru", **KW) for s in range(2)])
    assert SurrogateEngine(gru, n_envs=MEMBERS_MIN_BATCH).impl == "cell"
