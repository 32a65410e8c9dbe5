"""How parallelism enters the training loop: one small interface, one NaN rule.

:class:`Parallel` is what the epoch loop needs from "the other processes": the main-rank test,
sharding of a global batch, the backward + optimiser step, and broadcasts of rank 0's
decisions.  :class:`SingleProcess` is the plain one-process implementation;
:class:`~excavator_surrogate.scale.ddp.DistContext` implements the same interface for
data-parallel training (DDP).

**The NaN rule** (every path): an optimiser step is skipped, and its gradients dropped, when the
loss or the (clipped) gradient norm is not finite.  :func:`clip_and_step` is the one place that
applies it; under DDP the loss test is agreed by every rank and the norm is that of the
all-reduced gradient, so every rank skips the same steps.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch
from torch import nn

LrAt = Callable[[], float | None]
"""Per-step learning rate (None: leave the optimiser's, e.g. ReduceLROnPlateau's)."""


def clip_and_step(
    params: Iterable[torch.Tensor],
    opt: torch.optim.Optimizer,
    *,
    grad_clip: float,
    lr: float | None,
    loss_finite: bool,
) -> bool:
    """Clip the gradient norm to ``grad_clip`` (0: no clipping), then step unless the loss or
    the gradient norm is not finite; the gradients are zeroed either way.

    Returns:
        True if the optimiser stepped.
    """
    norm = torch.nn.utils.clip_grad_norm_(list(params), grad_clip if grad_clip > 0 else math.inf)
    ok = loss_finite and bool(torch.isfinite(norm))
    if ok:
        if lr is not None:
            for g in opt.param_groups:
                g["lr"] = lr
        opt.step()
    opt.zero_grad(set_to_none=True)
    return ok


@runtime_checkable
class Parallel(Protocol):
    """The training loop's view of the processes it runs in (see the module docstring).

    Every method may communicate: every rank calls them in the same order.
    """

    @property
    def is_main(self) -> bool:
        """True on the process that validates, writes checkpoints and logs."""
        ...

    world_size: int
    """Number of processes sharing each global batch."""
    device: torch.device
    """Training device of this process."""

    def wrap(self, net: nn.Module) -> Any:
        """The net as the loop should call it (DDP: gradients all-reduced in ``backward``)."""
        ...

    def shard_batch(self, batch: np.ndarray) -> tuple[np.ndarray, float, int]:
        """``(local indices, loss weight, real local samples)`` of one global batch."""
        ...

    def backward_step(
        self,
        loss: torch.Tensor,
        *,
        weight: float,
        net: Any,
        opt: torch.optim.Optimizer,
        grad_clip: float,
        lr_at: LrAt,
    ) -> bool:
        """Backward ``loss * weight``, clip, step under the NaN rule; True if it stepped."""
        ...

    def broadcast(self, obj: Any) -> Any:
        """Rank 0's picklable ``obj`` on every rank."""
        ...

    def broadcast_float(self, value: float | None) -> float | None:
        """Rank 0's float on every rank (cheap; None allowed)."""
        ...

    def global_loss(self, loss: float, count: int) -> tuple[float, int]:
        """Sample-weighted mean of the per-rank epoch losses and the global sample count."""
        ...

    def barrier(self) -> None:
        """Wait for every rank."""
        ...


@dataclass
class SingleProcess:
    """:class:`Parallel` for one process: no sharding, no communication."""

    device: torch.device
    """Training device."""
    world_size: int = 1
    """Always 1."""

    @property
    def is_main(self) -> bool:
        """Always True."""
        return True

    def wrap(self, net: nn.Module) -> nn.Module:
        """``net`` itself."""
        return net

    def shard_batch(self, batch: np.ndarray) -> tuple[np.ndarray, float, int]:
        """The whole batch, weight 1."""
        return batch, 1.0, len(batch)

    def backward_step(
        self,
        loss: torch.Tensor,
        *,
        weight: float,
        net: Any,
        opt: torch.optim.Optimizer,
        grad_clip: float,
        lr_at: LrAt,
    ) -> bool:
        """Backward (skipped for a non-finite loss), then :func:`clip_and_step`."""
        finite = bool(torch.isfinite(loss))
        if finite:
            (loss * weight if weight != 1.0 else loss).backward()
        return clip_and_step(
            net.parameters(), opt, grad_clip=grad_clip, lr=lr_at(), loss_finite=finite
        )

    def broadcast(self, obj: Any) -> Any:
        """``obj``."""
        return obj

    def broadcast_float(self, value: float | None) -> float | None:
        """``value``."""
        return value

    def global_loss(self, loss: float, count: int) -> tuple[float, int]:
        """``(loss, count)``."""
        return loss, count

    def barrier(self) -> None:
        """Nothing to wait for."""


def rank0_deadline(par: Parallel, deadline: float) -> Callable[[], bool]:
    """``past()``: True once rank 0's clock is past ``deadline`` (no communication without a
    finite deadline, one cheap broadcast per call with one)."""
    if not math.isfinite(deadline):
        return lambda: False
    if par.world_size == 1:
        return lambda: time.monotonic() > deadline
    return lambda: bool(par.broadcast_float(float(time.monotonic() > deadline)))
