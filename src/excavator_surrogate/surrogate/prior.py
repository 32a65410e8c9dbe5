"""The speed prior: a per-joint static valve map that a network's head corrects.

A valve-controlled hydraulic joint moves, to a first approximation, at a speed that is a
static function of its own command: nothing inside a dead zone, then a gain per direction.
:mod:`.structured` fits that map (with a delay) as a baseline, and on logs that drift from day
to day, or a test that drives the machine harder than its training did, it generalises better
than a network trained from scratch.  With ``ModelConfig.prior`` the network keeps it as the
base it corrects::

    omega[k+1] = s(u[k - d]) + y_std * head(h[k])      (no y_mean term)
    s_j(u)     = k_pos,j * max(u_j - a_pos,j, 0) - k_neg,j * max(a_neg,j - u_j, 0)

so an untrained head (output 0) is the structured model (without its end stops), and the
network only has to learn what the map misses (inertia, coupling, load, drift) - a smaller
signal than the speed itself, whose errors outside the training data stay smaller.  The map
reads only the current input row, so every path that runs the network (free run, envs, the
fused engine, ensemble merge, ONNX) adds it from the same row.  A joint whose map has a
delay ``d_j > 0`` reads its command ``d_j`` samples back: ``cols`` then points at the
delayed-command features (:meth:`.Normalization.with_lags`, carried as a delay line in the
command state ``z``), still one input row.  Training with a prior fits the delays as the
structured baseline does (up to 1 s, within the window); a joint put on the map after
training (:func:`.series.with_map_joints`) reads them the same way.

:func:`.structured.fit_prior` fits it by least squares on the training split (the
structured baseline's fit); the parameters live in the network's ``state_dict`` (buffers), so checkpoints
carry them and a resumed run keeps them.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from .features import Normalization

PRIOR_FIELDS = ("cols", "a_pos", "a_neg", "k_pos", "k_neg", "u_gain", "u_offset", "y_mean", "y_std")
"""Buffers of :class:`SpeedPrior`, all ``(n_joint,)``."""
PRIOR_MAP = ("cols", "a_pos", "a_neg", "k_pos", "k_neg")
"""The buffers that are the map itself (the others follow from the normalisation)."""


class SpeedPrior(nn.Module):
    """``x: (..., n_feature)`` normalised features -> ``(..., n_joint)`` the static map's speed,
    normalised like the target (``(s(u) - y_mean) / y_std``).

    Buffers, each ``(n_joint,)``: ``cols`` (long) the feature column of each joint's command;
    ``u_gain``, ``u_offset``: raw command ``u = x[cols] * u_gain + u_offset`` [command units];
    ``a_pos``, ``a_neg`` [command units], ``k_pos``, ``k_neg`` [rad/s per command unit] the map;
    ``y_mean``, ``y_std`` [rad/s] the target's normalisation.  A fresh prior is all zeros
    (``y_std`` ones): it adds nothing until :meth:`load_fit` or a ``state_dict`` fills it.
    """

    def __init__(self, n_joint: int) -> None:
        super().__init__()
        for name in PRIOR_FIELDS:
            if name == "cols":
                self.register_buffer(name, torch.arange(n_joint, dtype=torch.long))
            else:
                ones = name in ("y_std", "u_gain")
                self.register_buffer(name, torch.ones(n_joint) if ones else torch.zeros(n_joint))

    def load_fit(
        self,
        *,
        cols: Sequence[int],
        a_pos: Sequence[float],
        a_neg: Sequence[float],
        k_pos: Sequence[float],
        k_neg: Sequence[float],
        norm: Normalization,
    ) -> SpeedPrior:
        """Fill the buffers from a fitted map and the normalisation; returns self."""
        cols_t = torch.as_tensor(list(cols), dtype=torch.long)
        x_mean = norm.x_mean.detach().double().cpu()[cols_t]
        x_std = norm.x_std.detach().double().cpu()[cols_t]
        n = len(cols_t)
        u_center = norm.u_center.detach().double().cpu()[:n]
        u_scale = norm.u_scale.detach().double().cpu()[:n]
        values = {
            "cols": cols_t,
            "a_pos": a_pos,
            "a_neg": a_neg,
            "k_pos": k_pos,
            "k_neg": k_neg,
            # u = ((x * x_std + x_mean) * u_scale + u_center)
            "u_gain": x_std * u_scale,
            "u_offset": x_mean * u_scale + u_center,
            "y_mean": norm.y_mean.detach().double().cpu(),
            "y_std": norm.y_std.detach().double().cpu(),
        }
        with torch.no_grad():
            for name, v in values.items():
                buf = getattr(self, name)
                buf.copy_(torch.as_tensor(v, dtype=buf.dtype))
        return self

    def speed(self, u: torch.Tensor) -> torch.Tensor:
        """The map's speed [rad/s] of raw joint commands ``u: (..., n_joint)``."""
        return self.k_pos * torch.relu(u - self.a_pos) - self.k_neg * torch.relu(self.a_neg - u)

    def raw(self, x: torch.Tensor) -> torch.Tensor:
        """``x: (..., n_feature)`` normalised features -> ``(..., n_joint)`` the map's speed
        [rad/s]."""
        return self.speed(x[..., self.cols] * self.u_gain + self.u_offset)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x: (..., n_feature)`` -> ``(..., n_joint)`` normalised prior speed."""
        return (self.raw(x) - self.y_mean) / self.y_std

    def as_dict(self) -> dict[str, list[float]]:
        """The map per joint as plain numbers (for ``metrics.json`` and reports)."""
        return {n: getattr(self, n).tolist() for n in ("a_pos", "a_neg", "k_pos", "k_neg")}
