"""The one NaN rule: a step whose loss or gradient norm is not finite never updates the weights,
in one process (SingleProcess) and under DDP (DistContext, 2 gloo processes)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest
import torch
from torch import nn

from excavator_surrogate.scale.ddp import DistContext, spawn_local
from excavator_surrogate.surrogate import load_checkpoint
from excavator_surrogate.surrogate.model import SurrogateNet
from excavator_surrogate.training import (
    Parallel,
    SingleProcess,
    TrainConfig,
    clip_and_step,
    horizon_loss,
    train,
)
from tests.helpers.training import tiny_dataset, tiny_train_config


class _NanGrad(torch.autograd.Function):
    """Identity forward, NaN gradient backward: a finite loss with a NaN gradient."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        return x.view_as(x)

    @staticmethod
    def backward(ctx, g: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        return torch.full_like(g, math.nan)


def nan_grad_loss(y_hat: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """:func:`horizon_loss` (finite) whose gradient is NaN."""
    return horizon_loss(_NanGrad.apply(y_hat), y)


def _weights(net: nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in net.parameters()]


def _same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def _initial_net(cfg: TrainConfig, n_feature: int, n_joint: int) -> SurrogateNet:
    torch.manual_seed(cfg.seed)  # what train() does before building the net
    return SurrogateNet(cfg.model_config(n_feature, n_joint))


def test_clip_and_step_skips_non_finite_loss_or_gradient() -> None:
    torch.manual_seed(0)
    net = nn.Linear(3, 2)
    opt = torch.optim.Adam(net.parameters(), lr=0.1)
    x = torch.randn(5, 3)
    for grad_clip in (0.0, 1.0):
        before = _weights(net)
        nan_grad_loss(net(x), torch.zeros(5, 2)).backward()
        assert not clip_and_step(
            net.parameters(), opt, grad_clip=grad_clip, lr=None, loss_finite=True
        )
        assert _same(before, _weights(net))
        assert all(p.grad is None for p in net.parameters())
        net(x).pow(2).mean().backward()  # finite gradient, but the loss was declared non-finite
        assert not clip_and_step(
            net.parameters(), opt, grad_clip=grad_clip, lr=None, loss_finite=False
        )
        assert _same(before, _weights(net))
    net(x).pow(2).mean().backward()
    assert clip_and_step(net.parameters(), opt, grad_clip=1.0, lr=0.05, loss_finite=True)
    assert not _same(before, _weights(net))
    assert opt.param_groups[0]["lr"] == 0.05


def test_single_process_step_skips_nan_gradient_and_nan_loss() -> None:
    torch.manual_seed(0)
    net = nn.Linear(3, 2)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    par = SingleProcess(device=torch.device("cpu"))
    assert isinstance(par, Parallel)
    x = torch.randn(4, 3)
    before = _weights(net)
    kw = dict(weight=1.0, net=net, opt=opt, grad_clip=0.0, lr_at=lambda: None)
    assert not par.backward_step(nan_grad_loss(net(x), torch.zeros(4, 2)), **kw)
    assert not par.backward_step(net(x).sum() * math.nan, **kw)
    assert not par.backward_step(net(x).sum() + math.inf, **kw)  # inf loss, finite gradient
    assert _same(before, _weights(net))
    assert par.backward_step(net(x).pow(2).mean(), **kw)
    assert not _same(before, _weights(net))


@pytest.mark.parametrize("mode", ["windowed", "stateful"])
def test_training_with_nan_gradients_never_updates_the_weights(tmp_path: Path, mode: str) -> None:
    ds = tiny_dataset(2, n_train=2, n_step=120)
    cfg = tiny_train_config(mode=mode, epochs=2, patience=5, batch_size=32, horizon=2)
    init = _weights(_initial_net(cfg, ds.spec.n_feature, ds.spec.n_joint))
    best = load_checkpoint(
        train(cfg, ds, out=tmp_path / "nan", show_progress=False, loss=nan_grad_loss)
    )
    last = load_checkpoint(tmp_path / "nan" / "last.pt")
    assert _same(init, _weights(best.net)) and _same(init, _weights(last.net))
    log = (tmp_path / "nan" / "log.csv").read_text().splitlines()
    assert len(log) == 3 and all(",nan,0," in row for row in log[1:])  # train_loss nan, n_sample 0
    # the same run with the plain loss does move the weights (the check above can fail)
    ok = load_checkpoint(train(cfg, ds, out=tmp_path / "ok", show_progress=False))
    assert not _same(init, _weights(ok.net))


def _ddp_worker(ctx: DistContext, out: str) -> None:
    """Every rank: steps where only rank 1's gradient or loss is bad are skipped everywhere."""
    torch.set_num_threads(1)
    torch.manual_seed(0)
    net = nn.Linear(3, 2)
    ddp = ctx.wrap(net)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    assert isinstance(ctx, Parallel)
    x = torch.ones(4, 3) * (ctx.rank + 1)
    kw = dict(weight=1.0, net=ddp, opt=opt, grad_clip=1.0, lr_at=lambda: None)
    before = _weights(net)
    y = ddp(x)
    bad = _NanGrad.apply(y) if ctx.rank == 1 else y
    assert not ctx.backward_step(bad.pow(2).mean(), **kw)  # NaN gradient on rank 1 only
    y = ddp(x)
    assert not ctx.backward_step(y.pow(2).mean() + (math.inf if ctx.rank == 1 else 0.0), **kw)
    assert _same(before, _weights(net))
    assert ctx.backward_step(ddp(x).pow(2).mean(), **kw)
    assert not _same(before, _weights(net))
    ctx.assert_replicas_equal(list(net.parameters()))
    # the whole loop under DDP with a NaN-gradient loss
    ds = tiny_dataset(2, n_train=2, n_step=120)
    cfg = tiny_train_config(mode="windowed", epochs=1, batch_size=16, horizon=2)
    init = _weights(_initial_net(cfg, ds.spec.n_feature, ds.spec.n_joint))
    if ctx.is_main:  # rank 1 runs ahead to the first collective: it must write nothing, or
        # rank 0's check of the folder sees its files (its marker's temporary file: refused)
        time.sleep(3.0)
        assert not (Path(out) / "ddp_nan").exists()
    best = train(
        cfg, ds, out=Path(out) / "ddp_nan", show_progress=False, dist=ctx, loss=nan_grad_loss
    )
    assert _same(init, _weights(load_checkpoint(best).net))


def test_ddp_nan_gradient_on_one_rank_never_updates_the_weights(tmp_path: Path) -> None:
    spawn_local(_ddp_worker, nprocs=2, args=(str(tmp_path),))
