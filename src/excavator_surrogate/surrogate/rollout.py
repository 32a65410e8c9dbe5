"""Closed-loop (free-run) rollout of a surrogate driven by recorded commands.

Convention (see :mod:`.features`): the model consumes the features of sample ``k``
(``theta[k]``, ``u[k]``) and predicts ``omega[k+1]``; the angle integrates as
``theta[k+1] = theta[k] + T_s * omega_hat[k+1]``.  A rollout starts from a warm-up of ``W``
recorded samples (``theta[0..W-1]``, ``u[0..W-2]``); from then on only the recorded commands
are used.  Outputs for ``k < W`` are the recorded angles and NaN velocities.

- :class:`ClosedLoop`: batched runner with ``reset`` / ``step`` (what an environment wraps);
  windowed (zero state per window) or stateful (carried ``(h, c)``).
- :func:`rollout`: batched rollout of equal-length arrays; :func:`rollout_episodes` pads
  episodes of different lengths (causal, so padding never changes earlier samples).
- :func:`~.reference.rollout_reference` (its own module): the plain loop every batched or
  stateful path here is tested against.
- :func:`window_rollout`: the differentiable H-step windowed rollout used by the training loss.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from ..data.episode import Episode
from ..errors import ConfigError, DataError
from ..spec import MachineSpec
from .angles import integrate, omega_target
from .blocks import split
from .ensemble import member_head
from .features import Normalization
from .model import State, Surrogate
from .own_angles import network_inputs, own_advance, own_members, own_start
from .parallel import own_gain_dev

Mode = Literal["windowed", "stateful"]


def window_rollout(
    net: torch.nn.Module,
    norm: Normalization,
    x_win: torch.Tensor,
    theta: torch.Tensor,
    u_next: torch.Tensor,
    *,
    n_horizon: int,
    dt: float,
    limits: tuple[torch.Tensor, ...] | None = None,
    z_next: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Differentiable H-step windowed rollout (training loss, and the windowed closed loop).

    Args:
        net: windowed network ``(n_batch, W, n_feature) -> (n_batch, n_joint)``.
        norm: normalisation (encodes fed-back angles).
        x_win: (n_batch, W, n_feature) normalised features of samples ``t-W+1..t``.
        theta: (n_batch, n_joint) angle ``theta[t]`` [rad] that the first prediction integrates from.
        u_next: (n_batch, n_horizon - 1, n_joint) commands ``u[t+1..t+H-1]`` [command units].
        n_horizon: H, number of predicted steps.
        dt: sample period T_s [s].
        limits: the envelope ``(lo, hi[, omega_max])`` applied in the integration, or None.
        z_next: (n_batch, n_horizon - 1, P, n_joint) play states after ``u_next`` (with play
            features only).

    Returns:
        ``y``: (n_batch, H, n_joint) normalised predictions of ``omega[t+1..t+H]``;
        ``theta_hat``: (n_batch, H, n_joint) integrated angles ``theta[t+1..t+H]`` [rad].
    """
    ys, thetas = [], []
    for h in range(n_horizon):
        y = net(x_win)
        theta, omega = integrate(theta, norm.omega(y), dt=dt, limits=limits)
        ys.append(y)
        thetas.append(theta)
        if h < n_horizon - 1:
            z = None if z_next is None else z_next[:, h]
            row = norm.encode(theta, u_next[:, h], z, omega)
            x_win = torch.cat([x_win[:, 1:], row.unsqueeze(1)], dim=1)
    return torch.stack(ys, dim=1), torch.stack(thetas, dim=1)


class ClosedLoop:
    """Batched closed-loop runner: ``reset`` with a recorded history, then ``step`` with commands.

    Runs without gradients.  Tensors are on the surrogate's device/dtype; inputs may be NumPy.

    With ``members=True`` (a merged seed ensemble, :func:`.ensemble.member_head`) every step
    also sets :attr:`omega_members`, each member's own velocity from the same network call,
    and :attr:`follow` lets a row integrate one member's velocity instead of the mean.
    """

    def __init__(self, sur: Surrogate, *, mode: Mode | None = None, members: bool = False) -> None:
        self.sur = sur
        self.mode: Mode = mode or sur.mode
        if self.mode not in ("windowed", "stateful"):
            raise ConfigError(f"rollout mode must be windowed or stateful, got {self.mode!r}")
        if self.mode == "stateful" and not getattr(sur.net, "stateful_capable", False):
            raise ConfigError(
                f"model '{sur.name}' ({sur.model_cfg.cell}) cannot be stepped statefully"
            )
        self._device, self._dtype = sur.device, sur.dtype  # fixed for the loop's life
        self.norm = sur.norm.to(self._device, self._dtype)
        self.dt = sur.spec.dt
        self.theta: torch.Tensor | None = None
        """Current angle ``(n_batch, n_joint)`` [rad]."""
        self._rows: torch.Tensor | None = None
        self._state: State | None = None
        self.z: torch.Tensor | None = None
        """Play states ``(n_batch, P, n_joint)`` after the last command (P = 0: no play features)."""
        self.omega: torch.Tensor | None = None
        """Velocity feature of the current sample ``(n_batch, n_joint)`` [rad/s]: measured
        (history) or the last integrated prediction."""
        self._limits = sur.limits()
        self._head = member_head(sur) if members else None
        if members and self._head is None:
            raise ConfigError(
                f"model '{sur.name}' has no ensemble members to report (a single network, or "
                "merged by an older exsur: merge its members again with 'exsur merge')"
            )
        self._own_dev = own_gain_dev(sur).to(self._device, self._dtype) if members else None
        self.follow: torch.Tensor | None = None
        """With ``members``: ``(n_batch,)`` long, the member whose velocity row ``b``
        integrates (``-1``: the ensemble mean, i.e. the merged network; None: all rows)."""
        self.omega_members: torch.Tensor | None = None
        """With ``members``: ``(M, n_batch, n_joint)`` [rad/s], each member's predicted
        ``omega[k+1]`` at the last step (before the speed bound and end stops)."""

    def _t(self, a: np.ndarray | torch.Tensor) -> torch.Tensor:
        return torch.as_tensor(a, device=self._device, dtype=self._dtype)

    @property
    def window_rows(self) -> torch.Tensor | None:
        """Windowed: the last (at most ``W - 1``) encoded samples ``(n_batch, n, n_feature)``,
        oldest first, that the next step's window ends with (None: stateful, or before
        :meth:`reset`)."""
        return self._rows

    def reset_at(
        self,
        theta: np.ndarray,
        u: np.ndarray,
        starts: np.ndarray,
        *,
        n_hist: int | None = None,
    ) -> torch.Tensor:
        """:meth:`reset` with one batch row per measured start ``k`` of one episode: warmed
        up on ``theta[k - n_hist + 1 .. k]`` and the commands ``u[k - n_hist + 1 .. k - 1]``
        between them, so the next :meth:`step` (with ``u[k]``) predicts sample ``k + 1``.

        Args:
            theta: (n_step, n_joint) the episode's angles [rad]; ``u``: (n_step, n_u).
            starts: (n_start,) sample indices, each ``>= n_hist - 1``.
            n_hist: recorded samples per warm-up (default the model's window ``W``).
        """
        n = self.sur.window if n_hist is None else n_hist
        hist = np.asarray(starts)[:, None] + np.arange(-n + 1, 1)  # (n_start, n_hist)
        return self.reset(theta[hist], u[hist[:, :-1]])

    @torch.no_grad()
    def reset(
        self, theta_hist: np.ndarray | torch.Tensor, u_hist: np.ndarray | torch.Tensor
    ) -> torch.Tensor:
        """Warm up on recorded samples.

        Args:
            theta_hist: (n_batch, n_hist, n_joint) angles ``theta[0..n_hist-1]`` [rad], n_hist >= 1.
            u_hist: (n_batch, n_hist - 1, n_u) commands ``u[0..n_hist-2]`` (joints', then
                exogenous inputs'; ``n_u = spec.n_u``).

        In windowed mode only the last ``W`` samples matter; a shorter history is padded by
        repeating its first sample.  Play states (if the features have them) start at rest
        before ``u[0]``, and so does the velocity feature (0 at ``theta[0]``).  Returns the current angle ``theta[n_hist-1]``.
        """
        theta_hist = self._t(theta_hist)
        u_hist = self._t(u_hist)
        check_machine_shapes(theta_hist, u_hist, self.sur.spec, where="ClosedLoop.reset")
        require_finite(theta_hist, self.sur.spec, what="theta", where="ClosedLoop.reset")
        require_finite(u_hist, self.sur.spec, what="u", where="ClosedLoop.reset")
        n_batch, n_hist, _ = theta_hist.shape
        if n_hist < 1 or u_hist.shape != (n_batch, n_hist - 1, self.sur.spec.n_u):
            raise ValueError(
                f"reset needs theta_hist (n_batch, n_hist>=1, n_joint) and u_hist (n_batch, n_hist-1, n_u); "
                f"got {tuple(theta_hist.shape)} and {tuple(u_hist.shape)}"
            )
        z_hist = self.norm.play_seq(self.norm.play_rest(n_batch), u_hist)
        self.z = z_hist[:, -1] if n_hist > 1 else self.norm.play_rest(n_batch)
        w_hist = self.norm.velocity_seq(theta_hist, self.dt)  # (n_batch, n_hist, n_joint)
        self.omega = w_hist[:, -1]
        # the recorded history is what the network reads on every joint, its own angle included
        self.z = own_start(self.norm, self.z, theta_hist[:, -1], w_hist[:, -1])
        # (n_batch, n_hist-1, n_feature)
        rows = self.norm.encode(theta_hist[:, :-1], u_hist, z_hist, w_hist[:, :-1])
        self.theta = theta_hist[:, -1].clone()
        if self.mode == "windowed":
            w1 = self.sur.window - 1
            self._rows = rows[:, max(rows.shape[1] - w1, 0) :]
        else:
            state = self.sur.net.init_state(n_batch)
            if rows.shape[1] > 0:
                _, state = self.sur.net.forward_seq(rows, state)
            self._state = state
        return self.theta

    @torch.no_grad()
    def step(self, u: np.ndarray | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Apply commands ``u: (n_batch, n_u)`` at the current sample ``k``.

        Returns ``(theta[k+1], omega[k+1])``, each ``(n_batch, n_joint)`` [rad], [rad/s].
        """
        if self.theta is None:
            raise RuntimeError("call reset() before step()")
        u = self._t(u)
        require_finite(u, self.sur.spec, what="u", where="ClosedLoop.step")
        self.z = self.norm.play_update(self.z, u)
        theta_in, omega_in = network_inputs(self.norm, self.theta, self.z, self.omega)
        row = self.norm.encode(theta_in, u, self.z, omega_in)
        with self._head.capture() if self._head is not None else nullcontext():
            if self.mode == "windowed":
                x = torch.cat([self._rows, row.unsqueeze(1)], dim=1)
                if x.shape[1] < self.sur.window:  # short history: repeat its first sample
                    pad = x[:, :1].expand(x.shape[0], self.sur.window - x.shape[1], x.shape[2])
                    x = torch.cat([pad, x], dim=1)
                y = self.sur.net(x)
                self._rows = x[:, 1:]
            else:
                y, self._state = self.sur.net.step(row, self._state)
        if self._head is not None:
            y_m = self._head.outputs(row)  # (M, n_batch, n_joint), mean over M = y
            self.omega_members = self.norm.omega(y_m)
            if self.follow is not None:
                rows = torch.arange(y.shape[0], device=y.device)
                picked = y_m[self.follow.clamp(min=0), rows]
                y = torch.where((self.follow >= 0)[:, None], picked, y)
        omega = self.norm.omega(y)
        if self.norm.own is not None:  # map joints in parallel: the map's speed, own angle on
            omega, self.z = own_advance(
                self.norm, self.z, u, omega, dt=self.dt, limits=self._limits
            )
            if self._head is not None:
                omega = self._own_members(omega)
        self.theta, self.omega = integrate(self.theta, omega, dt=self.dt, limits=self._limits)
        return self.theta, self.omega

    def _own_members(self, omega: torch.Tensor) -> torch.Tensor:
        """With members and joints on a map in parallel: member ``m`` drives such a joint
        with gain ``1 + own_dev[m]`` (:func:`.parallel.own_gain_dev`); a row that follows a
        member integrates that member's; returns the speed to integrate."""
        assert self.omega_members is not None and self.norm.own is not None
        assert self._own_dev is not None
        om_m = own_members(self.norm, self.omega_members, omega, self._own_dev)
        self.omega_members = om_m
        if self.follow is None:
            return omega
        rows = torch.arange(omega.shape[0], device=omega.device)
        mine = om_m[self.follow.clamp(min=0), rows]
        return torch.where((self.follow >= 0)[:, None] & self.norm.own.own_mask, mine, omega)


def require_finite(
    a: np.ndarray | torch.Tensor, spec: MachineSpec, *, what: str, where: str
) -> None:
    """Refuse a NaN or infinite command or angle fed to a free run: one NaN command turns every
    joint's prediction NaN from that step on, and the coverage flags do not see it.

    Args:
        a: ``(..., n_u)`` commands [command units] (``what="u"``) or ``(..., n_joint)`` angles
            [rad] (``what="theta"``).
        spec: names the column.
        what: ``"u"`` or ``"theta"``.
        where: the call, for the message.

    Raises:
        ConfigError: one line naming the first non-finite entry's index and column.
    """
    ok = torch.isfinite(a).all() if isinstance(a, torch.Tensor) else np.isfinite(a).all()
    if ok:
        return
    arr = a.detach().cpu().numpy() if isinstance(a, torch.Tensor) else np.asarray(a)
    at = [int(i) for i in np.argwhere(~np.isfinite(arr))[0]]
    names = spec.u_names if what == "u" else spec.names
    raise ConfigError(
        f"{where}: {what}{at} ({names[at[-1]]}) is {arr[tuple(at)]}: a free run needs finite "
        "values; fill or cut the gap in the log (exsur import --nan)"
    )


def check_machine_shapes(
    theta: np.ndarray | torch.Tensor,
    u: np.ndarray | torch.Tensor,
    spec: MachineSpec,
    *,
    where: str,
) -> None:
    """Refuse angles and commands that are not batches of ``spec``'s machine: ``theta``
    (n_batch, n_step, n_joint) and ``u`` (n_batch, n_step', n_u), one batch size, the
    model's ``n_joint`` angles and ``n_u`` commands (joints', then exogenous inputs').

    Raises:
        DataError: one line naming the shapes, the model's joints and what to do.
    """
    joints = list(spec.names)
    want = f"theta (n_batch, n_step, {spec.n_joint}) and u (n_batch, n_step, {spec.n_u})"
    got = f"got theta {tuple(theta.shape)} and u {tuple(u.shape)}"
    if theta.ndim != 3 or u.ndim != 3:
        raise DataError(
            where,
            f"needs {want}, {got}",
            fix="add the batch axis, e.g. theta[None] and u[None] for one episode",
        )
    if theta.shape[0] != u.shape[0]:
        raise DataError(where, f"needs {want} of one batch size, {got}", fix="give one u per theta")
    if theta.shape[2] != spec.n_joint or u.shape[2] != spec.n_u:
        raise DataError(
            where,
            f"the model is of a machine with joints {joints} and commands "
            f"{list(spec.u_names)} ({want}), {got}",
            fix="use data of the model's machine, or a model trained on this machine",
        )


@torch.no_grad()
def rollout(
    sur: Surrogate,
    theta: np.ndarray,
    u: np.ndarray,
    *,
    warmup: int | None = None,
    mode: Mode | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Batched free-run over equal-length sequences.

    Args:
        sur: the surrogate (eval mode is set by the caller; :func:`load_checkpoint` does it).
        theta: (n_batch, >= warmup, n_joint) recorded angles; only ``theta[:, :warmup]`` is used.
        u: (n_batch, n_step, n_u) recorded commands [command units] (with exogenous inputs).
        warmup: recorded samples used to start (default ``sur.window``).
        mode: ``windowed`` / ``stateful`` (default: the mode the model was trained in).

    Returns:
        ``theta_hat``: (n_batch, n_step, n_joint) [rad], recorded for ``k < warmup``;
        ``omega_hat``: (n_batch, n_step, n_joint) [rad/s], NaN for ``k < warmup``.

    A merged ensemble of 256 units or more run statefully is stepped member by member
    (:func:`.blocks.split`: the same network without the zeros of its block-diagonal
    matrices, equal to float32 rounding).
    """
    warmup = sur.window if warmup is None else int(warmup)
    theta = np.asarray(theta, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    check_machine_shapes(theta, u, sur.spec, where="rollout")
    n_batch, n_step, _ = u.shape
    n_joint = sur.spec.n_joint
    if warmup < 1 or theta.shape[1] < warmup or n_step < warmup:
        raise ValueError(f"need >= warmup={warmup} samples, got theta {theta.shape}, u {u.shape}")
    require_finite(theta[:, :warmup], sur.spec, what="theta", where="rollout")
    require_finite(u[:, : n_step - 1], sur.spec, what="u", where="rollout")
    loop = ClosedLoop(sur if mode == "windowed" else split(sur), mode=mode)
    loop.reset(theta[:, :warmup], u[:, : warmup - 1])
    u_t = loop._t(u)
    th_out = torch.empty(n_batch, n_step, n_joint, dtype=sur.dtype, device=sur.device)
    om_out = torch.full_like(th_out, float("nan"))
    th_out[:, :warmup] = loop._t(theta[:, :warmup])
    for k in range(warmup - 1, n_step - 1):
        th_out[:, k + 1], om_out[:, k + 1] = loop.step(u_t[:, k])
    return th_out.double().cpu().numpy(), om_out.double().cpu().numpy()


@dataclass
class EpisodeRollout:
    """Free-run result for one episode, with its reference signals."""

    name: str
    time: np.ndarray
    """(n_step,) [s]."""
    theta_hat: np.ndarray
    """(n_step, n_joint) predicted angle [rad] (recorded during warm-up)."""
    omega_hat: np.ndarray
    """(n_step, n_joint) predicted velocity [rad/s] (NaN during warm-up)."""
    theta_ref: np.ndarray
    """(n_step, n_joint) reference angle [rad] (measured or true)."""
    omega_ref: np.ndarray
    """(n_step, n_joint) reference velocity = backward difference of ``theta_ref`` [rad/s]."""
    warmup: int
    """Samples excluded from metrics."""


def reference_theta(ep: Episode, reference: Literal["measured", "true"]) -> np.ndarray:
    """``(n_step, n_joint)`` angle of ``ep`` to start from and compare against."""
    if reference == "measured":
        return ep.theta
    if reference == "true":
        if ep.theta_true is None:
            raise DataError(
                f"episode '{ep.name}'",
                "has no ground truth (theta_<joint>_true columns: a simulated dataset with "
                "sensor faults has them, a machine's log does not)",
                fix="evaluate against the measured angles: --reference measured",
            )
        return ep.theta_true
    raise ConfigError(f"reference must be 'measured' or 'true', got {reference!r}")


def batch_episodes(
    episodes: Sequence[Episode],
    *,
    reference: Literal["measured", "true"],
    warmup: int,
    max_steps: int | None,
) -> tuple[list[np.ndarray], list[int], np.ndarray, np.ndarray]:
    """Episodes of different lengths as one free-run batch.

    Returns:
        ``thetas`` (each episode's reference angles, cut to ``max_steps``), ``lengths``,
        ``theta0: (n_batch, warmup, n_joint)`` the warm-up angles and
        ``u: (n_batch, n_max, n_u)`` the commands, shorter episodes padded with their last
        command (a causal model's output before the padding does not depend on it).

    Raises:
        DataError: an episode not longer than the warm-up.
    """
    thetas = [reference_theta(ep, reference)[:max_steps] for ep in episodes]
    us = [ep.u[:max_steps] for ep in episodes]
    lengths = [len(u) for u in us]
    for ep, n in zip(episodes, lengths):
        if n <= warmup:
            cut = " after max_steps" if n < len(ep.u) else ""
            raise DataError(
                f"episode '{ep.name}'",
                f"has {n} samples{cut}, not more than the warm-up of {warmup}",
                fix="use longer episodes or a shorter window"
                + (", or a larger max_steps" if cut else ""),
            )
    n_max = max(lengths)
    pad_u = np.stack([np.pad(u, ((0, n_max - len(u)), (0, 0)), mode="edge") for u in us])
    th0 = np.stack([t[:warmup] for t in thetas])
    return thetas, lengths, th0, pad_u


def rollout_episodes(
    sur: Surrogate,
    episodes: Sequence[Episode],
    *,
    reference: Literal["measured", "true"] = "measured",
    warmup: int | None = None,
    mode: Mode | None = None,
    max_steps: int | None = None,
) -> list[EpisodeRollout]:
    """Free-run every episode in one batch (shorter ones padded at the end with their last command).

    The warm-up uses the reference angle (``theta`` or ``theta_true``), so the surrogate and the
    reference start from the same state.  ``max_steps`` truncates long episodes.
    """
    if not episodes:
        return []
    warmup = sur.window if warmup is None else int(warmup)
    thetas, _, th0, pad_u = batch_episodes(
        episodes, reference=reference, warmup=warmup, max_steps=max_steps
    )
    th_hat, om_hat = rollout(sur, th0, pad_u, warmup=warmup, mode=mode)
    return episode_rollouts(episodes, thetas, th_hat, om_hat, sur=sur, warmup=warmup)


def episode_rollouts(
    episodes: Sequence[Episode],
    thetas: list[np.ndarray],
    theta_hat: np.ndarray,
    omega_hat: np.ndarray,
    *,
    sur: Surrogate,
    warmup: int,
) -> list[EpisodeRollout]:
    """Each episode's :class:`EpisodeRollout` from a padded batch free run
    (``theta_hat``, ``omega_hat``: (n_batch, n_max, n_joint)) and the reference angles
    ``thetas`` of :func:`batch_episodes`."""
    out = []
    for i, ep in enumerate(episodes):
        n = len(thetas[i])
        out.append(
            EpisodeRollout(
                name=ep.name,
                time=ep.time[:n],
                theta_hat=theta_hat[i, :n],
                omega_hat=omega_hat[i, :n],
                theta_ref=thetas[i],
                omega_ref=omega_target(thetas[i], sur.spec),
                warmup=warmup,
            )
        )
    return out
