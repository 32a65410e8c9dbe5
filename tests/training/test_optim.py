"""The optimiser of one training run: Adam, or AdamW with ``weight_decay``; the fused kernel
with portable numerics."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from excavator_surrogate import numerics
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.training.optim import Optimisation
from tests.helpers.training import tiny_train_config


def _step(cfg, *, grad: bool = False) -> tuple[torch.optim.Optimizer, torch.Tensor, torch.Tensor]:
    """One optimiser step on a small net: its optimiser, the weights before and after. Without
    ``grad`` every gradient is zero, so only the decay moves a weight."""
    torch.manual_seed(0)
    net = torch.nn.Linear(3, 2)
    before = net.weight.detach().clone()
    opt = Optimisation.build(cfg, SimpleNamespace(net=net)).opt
    if grad:
        net(torch.ones(4, 3)).square().sum().backward()
    else:
        for p in net.parameters():
            p.grad = torch.zeros_like(p)
    opt.step()
    return opt, before, net.weight.detach().clone()


def test_weight_decay_shrinks_every_weight_by_lr_times_decay_per_step():
    opt, before, after = _step(tiny_train_config(epochs=1, lr=1e-2, weight_decay=0.5))
    assert isinstance(opt, torch.optim.AdamW)
    # w <- w (1 - lr * weight_decay)
    torch.testing.assert_close(after, before * (1 - 1e-2 * 0.5))


def test_without_weight_decay_it_is_plain_adam():
    opt, before, after = _step(tiny_train_config(epochs=1, lr=1e-2))
    assert type(opt) is torch.optim.Adam
    assert torch.equal(after, before)


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_a_negative_or_non_finite_weight_decay_is_refused(bad):
    with pytest.raises(ConfigError, match="weight_decay"):
        tiny_train_config(weight_decay=bad)


def test_portable_numerics_step_adam_with_the_fused_kernel(monkeypatch):
    """VML's sqrt rounds differently from one CPU vendor to another; the fused kernel's does not."""
    steps = {}
    for mode, fused in (("native", None), ("portable", True)):
        monkeypatch.setenv(numerics.ENV, mode)
        assert numerics.fused_adam() is fused
        opt, _, steps[mode] = _step(tiny_train_config(epochs=1), grad=True)
        assert opt.param_groups[0]["fused"] is fused
    # the same Adam step either way, up to the last bits of the square root
    torch.testing.assert_close(steps["native"], steps["portable"])
