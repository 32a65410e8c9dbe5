"""Optimiser, learning-rate schedules and the weight average (EMA) of one training run."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import torch

from .. import numerics
from ..errors import CheckpointError
from ..surrogate.model import Surrogate
from .config import TrainConfig
from .parallel import LrAt


@dataclass
class Optimisation:
    """Adam (AdamW with ``weight_decay``; the fused CPU kernel with portable numerics),
    ReduceLROnPlateau and the optional EMA copy of the weights."""

    opt: torch.optim.Optimizer
    sched: Any  # torch.optim.lr_scheduler.ReduceLROnPlateau
    ema_sur: Surrogate | None
    """The surrogate with the averaged weights (None: ``ema_decay = 0``)."""

    @classmethod
    def build(cls, cfg: TrainConfig, sur: Surrogate) -> Optimisation:
        """Fresh optimiser state for ``sur.net``."""
        net = sur.net
        fused = numerics.fused_adam()
        opt: torch.optim.Optimizer
        if cfg.weight_decay > 0:
            # w <- w - lr * (adam_step(g) + weight_decay * w)      (decoupled decay, AdamW)
            opt = torch.optim.AdamW(
                net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, fused=fused
            )
        else:
            opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, fused=fused)
        ema_sur: Surrogate | None = None
        if cfg.ema_decay > 0:
            ema = torch.optim.swa_utils.AveragedModel(
                net, multi_avg_fn=torch.optim.swa_utils.get_ema_multi_avg_fn(cfg.ema_decay)
            )
            opt.register_step_post_hook(lambda *_: ema.update_parameters(net))
            ema_sur = replace(sur, net=ema.module)
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt,
            mode="min",
            factor=cfg.plateau_factor,
            patience=cfg.plateau_patience,
            min_lr=cfg.min_lr,
        )
        return cls(opt=opt, sched=sched, ema_sur=ema_sur)

    def state(self) -> dict[str, Any]:
        """Optimiser and scheduler state for ``last.pt``."""
        return {"optimizer": self.opt.state_dict(), "scheduler": self.sched.state_dict()}

    def load(self, ts: dict[str, Any], *, where: str) -> None:
        """Restore :meth:`state` from a checkpoint's ``train_state``.

        Raises:
            CheckpointError: the state does not fit this optimiser.
        """
        try:
            self.opt.load_state_dict(ts["optimizer"])
            self.sched.load_state_dict(ts["scheduler"])
        except (KeyError, ValueError, TypeError) as e:
            raise CheckpointError(
                f"{where}: optimiser state does not fit ({e}); resume from a matching last.pt"
            ) from e

    @property
    def lr(self) -> float:
        """Current learning rate."""
        return float(self.opt.param_groups[0]["lr"])


def cosine_lr(cfg: TrainConfig, epoch: int) -> LrAt:
    """Learning rate of the cosine schedule for ``epoch`` (None: leave it to ReduceLROnPlateau).

    The schedule depends on the planned epochs only, never on the wall clock, so the same data
    and seed train the same model on a fast, slow or busy computer:

        progress = epoch / epochs
        lr = min_lr + (lr_0 - min_lr) * (1 + cos(pi * progress)) / 2
    """
    if cfg.lr_schedule != "cosine":
        return lambda: None
    progress = min(epoch / cfg.epochs, 1.0)
    value = cfg.min_lr + 0.5 * (cfg.lr - cfg.min_lr) * (1.0 + math.cos(math.pi * progress))
    return lambda: value
