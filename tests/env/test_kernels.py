"""The stateful engine's recurrent kernels: a sequence call equals its steps, and every
implementation steps the same folded layers."""

from __future__ import annotations

import pytest
import torch

from excavator_surrogate.env.fused import FusedStep
from excavator_surrogate.env.kernels import RecurrentKernel
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.ensemble import merge

KW = dict(mode="stateful", end_stops=True, play=(0.05,), omega_in=True)


def _state(kernel: RecurrentKernel, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A random dense state (n_layer, n, hidden) in the kernel's layout."""
    g = torch.Generator().manual_seed(seed)
    h = torch.randn(kernel.n_layer, n, kernel.hidden, generator=g) * 0.5
    c = torch.randn(kernel.n_layer, n, kernel.hidden, generator=g) * 0.5
    return kernel.from_dense(h, c)


@pytest.mark.parametrize("cell", ["lstm", "gru"])
def test_every_kernel_steps_the_same_layers(make_surrogate, cell) -> None:
    """From one random state, ``seq`` over 7 samples equals ``cells`` looped sample by sample,
    in every implementation (members: a merged LSTM ensemble of 3), and all equal the cell
    kernel; ``step`` is the head's hidden layer on ``cells``' output."""
    sur = merge([make_surrogate(seed=s, hidden=8, cell=cell, **KW) for s in range(3)])
    fused = FusedStep(sur)
    impls = ["cell", "module"] + (["members"] if cell == "lstm" else [])
    kernels = {k: RecurrentKernel(fused, n_envs=5, impl=k, name="t") for k in impls}
    assert {k: v.impl for k, v in kernels.items()} == {k: k for k in impls}
    x = torch.randn(5, 7, fused.n_raw, generator=torch.Generator().manual_seed(1))
    ref = None
    for kernel in kernels.values():
        h0, c0 = _state(kernel, 5, seed=2)
        out_seq, h_seq, c_seq = kernel.seq(x, h0, c0)
        h, c = h0, c0
        for j in range(x.shape[1]):
            out, h, c = kernel.cells(x[:, j], h, c)
        torch.testing.assert_close(out_seq, out, atol=1e-5, rtol=0)
        dense = kernel.dense(h_seq, c_seq)
        torch.testing.assert_close(dense[0], kernel.dense(h, c)[0], atol=1e-5, rtol=0)
        a, _, _ = kernel.step(x[:, 0], h0, c0)
        first, _, _ = kernel.cells(x[:, 0], h0, c0)
        w1, b1, _, _ = kernel.head
        torch.testing.assert_close(a, torch.relu(first @ w1.t() + b1), atol=1e-5, rtol=0)
        if ref is None:
            ref = (out_seq, dense[0])
        else:
            torch.testing.assert_close(out_seq, ref[0], atol=1e-5, rtol=0)
            torch.testing.assert_close(dense[0], ref[1], atol=1e-5, rtol=0)


def test_member_layout_round_trips(make_surrogate) -> None:
    """``dense`` and ``from_dense`` are inverse in the members' layout (n_layer, M, n, width),
    and ``dense(row=)`` is that env's slice."""
    sur = merge([make_surrogate(seed=s, hidden=8, **KW) for s in range(2)])
    kernel = RecurrentKernel(FusedStep(sur), n_envs=3, impl="members", name="t")
    assert kernel.state_shape(3) == (2, 2, 3, 8)
    h, c = _state(kernel, 3, seed=4)
    assert h.shape == (2, 2, 3, 8)
    hd, cd = kernel.dense(h, c)
    assert hd.shape == (2, 3, 16)
    h2, c2 = kernel.from_dense(hd, cd)
    torch.testing.assert_close(h2, h, atol=0, rtol=0)
    torch.testing.assert_close(c2, c, atol=0, rtol=0)
    h1, _ = kernel.dense(h, c, row=1)
    torch.testing.assert_close(h1, hd[:, 1:2], atol=0, rtol=0)


def test_an_unknown_kernel_is_refused(make_surrogate) -> None:
    fused = FusedStep(make_surrogate(seed=0, hidden=8, **KW))
    with pytest.raises(ConfigError, match="impl must be 'auto', 'cell', 'module' or 'members'"):
        RecurrentKernel(fused, n_envs=1, impl="fast", name="t")  # type: ignore[arg-type]
