"""Training modes: how an epoch is cut into batches and what the net predicts for a batch.

Both modes produce the same :class:`~excavator_surrogate.surrogate.model.SurrogateNet`; the
epoch loop (:mod:`.loop`) is the same for both.  A mode has two methods:

- ``batches(rng, world)``: the epoch's global batches (arrays of global sample indices);
- ``predict(net, index, epoch)``: yields ``(y_hat, y, n_step)`` pieces for one (rank's share
  of a) batch, one per optimiser step; the loop computes the loss, steps, then resumes the
  generator.  ``n_step`` is the number of target steps per sequence that the piece's mean loss
  covers (for the epoch's sample-weighted train loss).

``windowed`` (paper III-B): a sample is a window of ``W`` recorded samples ending at ``t``; the
net (zero initial state) predicts ``omega[t+1]``, which is integrated into the angle, re-encoded
with the recorded command ``u[t+1]`` and appended to the window, ``H`` times.  Cost per epoch
~ ``n_sample * W * H`` recurrent steps.

``stateful`` (faster): random sub-sequences of ``seq_len`` samples; the first ``burn_in``
samples are fed with recorded angles without gradient to build up ``(h, c)``; the rest is
either teacher-forced (recorded angles, one fused recurrent call) or free-run (integrated
angles fed back), with truncated BPTT: every ``tbptt`` steps the loss is back-propagated, the
optimiser steps and state/angle are detached.  Cost per epoch ~ ``n_sample`` recurrent steps.

With ``bootstrap`` both modes draw from the network's own bootstrap resample of the training
episodes (:func:`~.batches.bootstrap_counts`, fixed by its seed): seed-ensemble members then
differ by their data as well as by their seed (bagging).

Adding a mode: a class here with these two methods, registered in :data:`MODES` (its name and
its own knobs go into :class:`~.config.TrainConfig` and ``MODE_FIELDS``).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import torch

from ..surrogate.angles import integrate
from ..surrogate.model import Surrogate
from ..surrogate.rollout import window_rollout
from .batches import (
    TrainData,
    bootstrap_counts,
    global_batches,
    sequence_cap,
    sequence_starts,
    windowed_indices,
)
from .config import TrainConfig
from .free_run import free_run_chunk, supported

Piece = tuple[torch.Tensor, torch.Tensor, int]
"""``(y_hat, y, n_step)``: predictions and targets ``(n_batch, n_step, n_joint)``."""


class Mode(Protocol):
    """A training mode (see the module docstring)."""

    def batches(self, rng: np.random.Generator, world: int) -> list[np.ndarray]:
        """The epoch's global batches (``world`` ranks share each)."""
        ...

    def predict(self, net: Any, index: np.ndarray, epoch: int) -> Iterator[Piece]:
        """Predictions for the samples ``index``, one piece per optimiser step."""
        ...


@dataclass
class Windowed:
    """Sliding windows with an ``H``-step rollout per sample (paper III-B)."""

    cfg: TrainConfig
    data: TrainData
    sur: Surrogate
    _ar: dict[str, torch.Tensor] = field(init=False, repr=False)
    _limits: Any = field(init=False, repr=False)
    _counts: np.ndarray | None = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._counts = _bootstrap(self.cfg, self.data)
        dev, w, h = self.data.x.device, self.cfg.window, self.cfg.horizon
        self._ar = {
            "w": torch.arange(-w + 1, 1, device=dev),
            "u": torch.arange(1, h, device=dev),
            "y": torch.arange(1, h + 1, device=dev),
        }
        self._limits = self.sur.limits()

    def batches(self, rng: np.random.Generator, world: int) -> list[np.ndarray]:
        """Shuffled window ends, capped at ``epoch_samples``, ``batch_size * world`` per batch."""
        idx = windowed_indices(self.data, self.cfg.window, self.cfg.horizon, self._counts)
        rng.shuffle(idx)
        if self.cfg.epoch_samples > 0:
            idx = idx[: self.cfg.epoch_samples]
        return global_batches(idx, self.cfg.batch_size * world)

    def predict(self, net: Any, index: np.ndarray, epoch: int) -> Iterator[Piece]:
        """One piece: the ``H``-step rollouts of the windows ending at ``index``."""
        data, ar = self.data, self._ar
        t = torch.as_tensor(index, device=data.x.device)
        y_hat, _ = window_rollout(
            net,
            self.sur.norm,
            data.x[t[:, None] + ar["w"]],
            data.theta[t],
            data.u[t[:, None] + ar["u"]],
            z_next=data.z[t[:, None] + ar["u"]],
            n_horizon=self.cfg.horizon,
            dt=self.sur.spec.dt,
            limits=self._limits,
        )
        yield y_hat, data.y[t[:, None] + ar["y"]], 1


@dataclass
class Stateful:
    """Sub-sequences with a burn-in and truncated BPTT, teacher-forced or free-run."""

    cfg: TrainConfig
    data: TrainData
    sur: Surrogate
    _limits: Any = field(init=False, repr=False)
    _counts: np.ndarray | None = field(init=False, repr=False)
    _fused: bool = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._counts = _bootstrap(self.cfg, self.data)
        self._fused = self.cfg.fused_backward and supported(self.sur.net)
        self._limits = self.sur.limits()
        spec = self.sur.spec
        # in the feature layout: the (sin, cos) columns of each periodic joint, and the angle
        # column of each other joint with its drift's end std [feature units]:
        # angle_noise * std_j(theta) / x_std
        turn: list[tuple[int, int, int]] = []
        self._noise: list[tuple[int, float]] = []
        k = 0
        for j, p in enumerate(spec.periodic):
            if p:
                turn.append((j, k, k + 1))
            elif self.cfg.angle_noise > 0:
                std = float(self.data.theta[..., j].std()) / float(self.sur.norm.x_std[k])
                self._noise.append((k, self.cfg.angle_noise * std))
            k += 2 if p else 1
        self._turn = turn if self.cfg.periodic_offsets else []

    def _turned(
        self, x: torch.Tensor, theta: torch.Tensor, index: np.ndarray, epoch: int
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``x`` (n_batch, n_step, n_feature) and ``theta`` (n_batch, n_step, n_joint) with each
        sub-sequence's periodic joints turned by an offset phi ~ U[0, 2 pi), drawn from the
        seed, the epoch and the sub-sequence's start (the same on every machine)."""
        if not self._turn:
            return x, theta
        norm = self.sur.norm
        rng = np.random.default_rng([self.cfg.seed, epoch, *(int(i) for i in index[:1])])
        phi = rng.uniform(0.0, 2.0 * np.pi, (len(index), len(self._turn)))
        phi_t = torch.as_tensor(phi, dtype=theta.dtype, device=theta.device)[:, None, :]
        x, theta = x.clone(), theta.clone()
        for n, (j, cs, cc) in enumerate(self._turn):
            th = theta[..., j] + phi_t[..., n]
            theta[..., j] = th
            # x = (raw - x_mean) / x_std, raw = sin(theta + phi), cos(theta + phi)
            x[..., cs] = (torch.sin(th) - norm.x_mean[cs]) / norm.x_std[cs]
            x[..., cc] = (torch.cos(th) - norm.x_mean[cc]) / norm.x_std[cc]
        return x, theta

    def _drifted(self, x: torch.Tensor, index: np.ndarray, epoch: int) -> torch.Tensor:
        """``x`` (n_batch, n_step, n_feature) with each non-periodic joint's angle feature
        drifting by a random walk from 0 at the burn-in's end (``angle_noise``), drawn from the
        seed, the epoch and the sub-sequence's start (the same on every machine)::

            x[k, col_j] += sigma_j * sqrt(1 / n) * sum_{i <= k} e_i,   e_i ~ N(0, 1)

        with ``n`` the steps after the burn-in and ``sigma_j`` the walk's end standard
        deviation in feature units."""
        if not self._noise:
            return x
        b0 = max(self.cfg.burn_in - 1, 0)
        n = x.shape[1] - b0
        rng = np.random.default_rng([self.cfg.seed, epoch, *(int(i) for i in index[:1]), 1])
        e = rng.standard_normal((len(index), n, len(self._noise)))
        walk = np.cumsum(e, axis=1) * np.sqrt(1.0 / n) * [s for _, s in self._noise]
        walk_t = torch.as_tensor(walk, dtype=x.dtype, device=x.device)
        x = x.clone()
        for m, (col, _) in enumerate(self._noise):
            x[:, b0:, col] += walk_t[..., m]
        return x

    def _blanked(self, x: torch.Tensor, index: np.ndarray, epoch: int) -> torch.Tensor:
        """``x`` (n_batch, n_step, n_feature) with the exogenous inputs' features set to 0
        (their training mean) over the whole of each sub-sequence drawn with probability
        ``input_dropout``, from the seed, the epoch and the sub-sequence's start (the same on
        every machine): what the network sees with its input weights of them zeroed."""
        spec = self.sur.spec
        if self.cfg.input_dropout <= 0 or not spec.n_input:
            return x
        rng = np.random.default_rng([self.cfg.seed, epoch, *(int(i) for i in index[:1]), 2])
        off = torch.as_tensor(rng.random(len(index)) < self.cfg.input_dropout)
        x = x.clone()
        x[off, :, spec.input_features] = 0.0
        return x

    def batches(self, rng: np.random.Generator, world: int) -> list[np.ndarray]:
        """Shuffled sub-sequence starts, capped at ``epoch_samples``, ``seq_batch * world`` per batch."""
        cfg = self.cfg
        starts = sequence_starts(self.data, cfg.seq_len, cfg.burn_in, rng, self._counts)
        rng.shuffle(starts)
        cap = sequence_cap(cfg.epoch_samples, seq_len=cfg.seq_len, burn_in=cfg.burn_in)
        if cap is not None:
            starts = starts[:cap]
        return global_batches(starts, cfg.seq_batch * world)

    def predict(self, net: Any, index: np.ndarray, epoch: int) -> Iterator[Piece]:
        """One piece per TBPTT chunk after the burn-in; state and angle are detached between."""
        cfg, data, norm = self.cfg, self.data, self.sur.norm
        dt, limits = self.sur.spec.dt, self._limits
        teacher = cfg.teacher_forced(epoch)
        s = torch.as_tensor(index, device=data.x.device)
        g = s[:, None] + torch.arange(cfg.seq_len, device=data.x.device)
        x_seq, th_seq, u_seq, y_seq = data.x[g], data.theta[g], data.u[g], data.y[g + 1]
        x_seq, th_seq = self._turned(x_seq, th_seq, index, epoch)
        if teacher:
            x_seq = self._blanked(self._drifted(x_seq, index, epoch), index, epoch)
        z_seq, w_seq = data.z[g], data.w[g]
        state = net.init_state(len(s))
        b0 = cfg.burn_in - 1  # first step whose output is in the loss
        if b0 > 0:
            with torch.no_grad():
                _, state = net.forward_seq(x_seq[:, :b0], state)
        theta, omega = th_seq[:, b0], w_seq[:, b0]
        for j0 in range(b0, cfg.seq_len, cfg.tbptt):
            j1 = min(j0 + cfg.tbptt, cfg.seq_len)
            if teacher:
                y_hat, state = net.forward_seq(x_seq[:, j0:j1], state)
            elif self._fused and net is self.sur.net:
                y_hat, state, theta, omega = free_run_chunk(
                    net,
                    norm,
                    theta=theta,
                    omega=omega,
                    state=state,
                    u=u_seq[:, j0:j1],
                    z=z_seq[:, j0:j1],
                    dt=dt,
                    limits=limits,
                )
            else:
                ys = []
                for j in range(j0, j1):
                    x = norm.encode(theta, u_seq[:, j], z_seq[:, j], omega)
                    y, state = net.step(x, state)
                    theta, omega = integrate(theta, norm.omega(y), dt=dt, limits=limits)
                    ys.append(y)
                y_hat = torch.stack(ys, dim=1)
            yield y_hat, y_seq[:, j0:j1], y_hat.shape[1]
            state = (state[0].detach(), state[1].detach())
            theta, omega = theta.detach(), omega.detach()


def _bootstrap(cfg: TrainConfig, data: TrainData) -> np.ndarray | None:
    """(n_episode,) copies of each training episode in this network's bootstrap resample
    (``cfg.bootstrap``, drawn from ``cfg.seed``), or None: every episode once."""
    return bootstrap_counts(len(data.starts), cfg.seed) if cfg.bootstrap else None


MODES: dict[str, type[Windowed] | type[Stateful]] = {"windowed": Windowed, "stateful": Stateful}
"""Training modes by ``[train] mode`` name."""


def make_mode(cfg: TrainConfig, data: TrainData, sur: Surrogate) -> Mode:
    """The strategy of ``cfg.mode`` over ``data`` for the surrogate ``sur``."""
    return MODES[cfg.mode](cfg=cfg, data=data, sur=sur)
