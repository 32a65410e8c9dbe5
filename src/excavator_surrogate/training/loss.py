"""The training loss: ``loss(y_hat, y) -> scalar``, passed into the epoch loop.

Changing the loss touches this module only (or pass ``loss=`` to
:func:`~excavator_surrogate.training.api.train`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import torch
import torch.nn.functional as F

LossFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""``loss(y_hat, y) -> scalar`` on normalised velocities, both ``(n_batch, n_step, n_joint)``
(``n_step`` = H in windowed mode, one TBPTT chunk in stateful mode)."""


def horizon_loss(y_hat: torch.Tensor, y: torch.Tensor, *, lambda_bias: float = 0.0) -> torch.Tensor:
    """Paper III-B loss on normalised velocities.

    Args:
        y_hat: (n_batch, H, n_joint) predictions.
        y: (n_batch, H, n_joint) targets.
        lambda_bias: weight of ``|| mean_h y_hat - mean_h y ||^2`` (summed over joints, mean over batch).

    Returns:
        Scalar ``mean SmoothL1(y_hat, y) + lambda_bias * L_bias``.
    """
    loss = F.smooth_l1_loss(y_hat, y, beta=1.0)
    if lambda_bias > 0:
        bias = (y_hat.mean(dim=1) - y.mean(dim=1)).pow(2).sum(dim=-1).mean()
        loss = loss + lambda_bias * bias
    return loss


def default_loss(*, lambda_bias: float) -> LossFn:
    """The loss :func:`train` uses unless given one: :func:`horizon_loss` with ``lambda_bias``."""
    return partial(horizon_loss, lambda_bias=lambda_bias)
