"""The free run of stateful LSTM networks in NumPy: :func:`rollout_numpy`.

Training validates its candidates (the raw and the averaged weights) by a free run of the
whole validation split, every validated epoch.  On a long operator log that is a few
thousand steps of a 2 x 128 LSTM on two rows, and each step is a few dozen tiny operations:
torch's dispatch of one (2-3 µs) costs more than its arithmetic, and the free runs took about
as long as the training epochs themselves.  This loop does the same maths in NumPy (about
1 µs an operation), but for the matrix products, which run in torch on the caller's
threads (NumPy's BLAS would start threads of its own beside the other trainings).  It
computes everything that does not depend on the fed-back angle once for the whole episode,
in torch, before the loop: the command columns (scaled commands, play features, delayed
commands) and a static-map prior's term.  One step::

    x_k = [(a(theta_k) - mean_a) / std_a,  cmd_k,  (omega_k - mean_w) / std_w]
    gates = [inp, h_l] [W_ih,l ; W_hh,l]^T + b_l                       per layer l
    c_l <- sigmoid(f) c_l + sigmoid(i) tanh(g);   h_l <- inp <- sigmoid(o) tanh(c_l)
    y = W2 relu(W1 h + b1) + b2  (+ x_k's velocity columns if residual)  (+ prior_k)
    omega[k+1] = clip(y std_y + mean_y, -omega_max, omega_max)
    theta[k+1] = clip(theta[k] + T_s omega[k+1], theta_min, theta_max)

with ``a(theta)`` the angle columns (sin and cos of a periodic joint).  It is what
:class:`~.rollout.ClosedLoop` computes for a stateful network, summed in another order, so
the results agree to float32 rounding, not bit for bit (tested against it and against the
plain loop).  The warm-up runs in torch (:meth:`~.rollout.ClosedLoop.reset`).

Networks whose angle inputs are their own (joints on a map in parallel, ``norm.own``) are
not covered (:func:`numpy_capable`); :func:`~.rollout.rollout` steps them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ..data.episode import Episode
from .angles import integrate_np
from .features_np import angle_columns_np
from .model import Surrogate, SurrogateNet
from .rollout import ClosedLoop, EpisodeRollout, batch_episodes, episode_rollouts, require_finite
from .stacked import StackedNet


def _nets(sur: Surrogate) -> list[SurrogateNet] | None:
    """The LSTM networks of ``sur`` side by side (one, or a :class:`StackedNet`'s), or None."""
    net = sur.net
    nets = list(net._nets) if isinstance(net, StackedNet) else [net]
    if not all(isinstance(n, SurrogateNet) and n.cfg.cell == "lstm" for n in nets):
        return None
    return nets  # type: ignore[return-value]


def _n_cmd_end(sur: Surrogate) -> int:
    """The column after the command columns (the velocity feature's first, or the end)."""
    return sur.norm.n_feature - (sur.spec.n_joint if sur.norm.omega_in else 0)


def numpy_capable(sur: Surrogate) -> bool:
    """Whether :func:`rollout_numpy` can run ``sur``: stateful LSTM networks (one, or a
    :func:`~.stacked.stack` of them) on the CPU, whose angle inputs are the fed-back angles
    (no ``norm.own``), and whose static-map prior (if any) reads command columns only."""
    nets = _nets(sur)
    if nets is None or sur.mode != "stateful" or sur.device.type != "cpu":
        return False
    if sur.norm.own is not None:
        return False
    if nets[0].cfg.prior:
        lo, hi = sur.norm.n_angle, _n_cmd_end(sur)
        for n in nets:
            cols = n.prior.cols
            if bool(((cols < lo) | (cols >= hi)).any()):
                return False
    return True


def _affine(x: np.ndarray, w: torch.Tensor, b: torch.Tensor) -> np.ndarray:
    """``x @ w + b`` per candidate: ``x (C, n, k)``, ``w (C, k, m)``, ``b (C, 1, m)`` ->
    ``(C, n, m)``.  In torch, on the caller's threads: NumPy's BLAS would start threads of
    its own beside the other trainings (on h1-dev's 48 rows, a validation took 30 s instead
    of 1)."""
    return torch.baddbmm(b, torch.from_numpy(x), w).numpy()


@torch.no_grad()
def _commands(
    sur: Surrogate, nets: list[SurrogateNet], u: torch.Tensor, z0: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The command columns of every step and each candidate's prior term.

    Args:
        u: (C * n, n_run, n_u) the commands ``u[k]`` of the steps, in order.
        z0: (C * n, P + L, n_joint) the command state before the first of them.

    Returns:
        ``cmd``: (C * n, n_run, n_cmd) normalised command columns (as ``norm.encode`` gives);
        ``prior``: (C * n, n_run, n_joint) each row's candidate's normalised prior speed, or
        None without a prior.
    """
    norm = sur.norm
    z = norm.play_seq(z0, u) if norm.n_command else None
    raw = norm.command_raw(u, z)  # (C * n, n_run, n_cmd)
    lo, hi = norm.n_angle, _n_cmd_end(sur)
    cmd = (raw - norm.x_mean[lo:hi]) / norm.x_std[lo:hi]
    if not nets[0].cfg.prior:
        return cmd, None
    x = cmd.new_zeros(*cmd.shape[:-1], norm.n_feature)
    x[..., lo:hi] = cmd  # the prior reads command columns only (numpy_capable)
    rows = x.chunk(len(nets))
    prior = torch.cat([n.prior(r) for n, r in zip(nets, rows, strict=True)])
    return cmd, prior


def _sigmoid(x: np.ndarray) -> np.ndarray:
    # sigmoid(x) = 1 / (1 + exp(-x))
    return 1.0 / (1.0 + np.exp(-x))


@torch.no_grad()
def rollout_numpy(
    sur: Surrogate, theta: np.ndarray, u: np.ndarray, *, warmup: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~.rollout.rollout` of a :func:`numpy_capable` surrogate, stepped in NumPy.

    Args:
        sur: stateful LSTM network(s), in eval mode.
        theta: (n_batch, >= warmup, n_joint) recorded angles [rad]; ``theta[:, :warmup]`` is used.
        u: (n_batch, n_step, n_u) recorded commands [command units].
        warmup: recorded samples used to start (>= 1).

    Returns:
        ``theta_hat``, ``omega_hat``: (n_batch, n_step, n_joint) [rad], [rad/s] (float64),
        recorded angles and NaN velocities for ``k < warmup``.
    """
    nets = _nets(sur)
    if nets is None or not numpy_capable(sur):
        raise ValueError(f"model '{sur.name}' cannot be stepped in NumPy: use rollout()")
    theta = np.asarray(theta, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    n_batch, n_step, _ = u.shape
    n_joint, n_cand = sur.spec.n_joint, len(nets)
    if warmup < 1 or theta.shape[1] < warmup or n_step < warmup:
        raise ValueError(f"need >= warmup={warmup} samples, got theta {theta.shape}, u {u.shape}")
    if n_batch % n_cand:
        raise ValueError(f"{n_batch} rows do not split into {n_cand} candidates' copies")
    require_finite(u[:, : n_step - 1], sur.spec, what="u", where="rollout_numpy")
    loop = ClosedLoop(sur)
    loop.reset(theta[:, :warmup], u[:, : warmup - 1])
    u_run = loop._t(u[:, warmup - 1 : n_step - 1])  # u[k] of the steps k = warmup-1 .. n_step-2
    z0 = loop.z if loop.z is not None else loop.norm.play_rest(n_batch)
    cmd_t, prior_t = _commands(sur, nets, u_run, z0)
    dt_np = np.dtype(str(sur.dtype).removeprefix("torch."))
    cmd = np.ascontiguousarray(cmd_t.cpu().numpy().transpose(1, 0, 2))  # (n_run, n_batch, ·)
    prior = None if prior_t is None else prior_t.cpu().numpy().transpose(1, 0, 2)
    # per layer W (C, n_in + hidden, 4 hidden) = [W_ih ; W_hh]^T and b (C, 1, 4 hidden), then
    # the head's two layers: the stacked candidates' own copies (a single network's built)
    cfg = nets[0].cfg
    stacked = sur.net if isinstance(sur.net, StackedNet) else StackedNet(nets)
    ws, (w1, w2) = stacked._w[: cfg.n_layer], stacked._w[cfg.n_layer :]
    bs, (b1, b2) = stacked._b[: cfg.n_layer], stacked._b[cfg.n_layer :]
    norm = loop.norm
    n_ang, hi_c = norm.n_angle, _n_cmd_end(sur)
    x_mean = norm.x_mean.cpu().numpy()
    x_std = norm.x_std.cpu().numpy()
    a_mean, a_std = x_mean[:n_ang], x_std[:n_ang]
    w_mean, w_std = x_mean[hi_c:], x_std[hi_c:]
    y_mean, y_std = norm.y_mean.cpu().numpy(), norm.y_std.cpu().numpy()
    limits = sur.limits_np()
    limits = None if limits is None else tuple(np.asarray(v, dtype=dt_np) for v in limits)
    dt = dt_np.type(sur.spec.dt)
    h0, c0 = loop._state  # each (n_layer, n_batch, hidden)
    h = [h0[k].cpu().numpy().reshape(n_cand, -1, cfg.hidden) for k in range(cfg.n_layer)]
    c = [c0[k].cpu().numpy().reshape(n_cand, -1, cfg.hidden) for k in range(cfg.n_layer)]
    th = loop.theta.cpu().numpy()
    om = loop.omega.cpu().numpy()
    hid = cfg.hidden
    th_out = np.empty((n_batch, n_step, n_joint))
    om_out = np.full_like(th_out, np.nan)
    th_out[:, :warmup] = theta[:, :warmup].astype(dt_np)
    with np.errstate(over="ignore", invalid="ignore"):
        for t in range(n_step - warmup):
            # x = [(a(theta) - mean) / std, cmd, (omega - mean) / std]       (n_batch, n_feature)
            parts = [(angle_columns_np(th, norm.periodic) - a_mean) / a_std, cmd[t]]
            if norm.omega_in:
                parts.append((om - w_mean) / w_std)
            x = np.concatenate(parts, axis=-1)
            inp = x.reshape(n_cand, -1, x.shape[-1])
            for k in range(cfg.n_layer):
                # gates = [x, h] W^T + b                                  (C, n, 4 hidden)
                gates = _affine(np.concatenate([inp, h[k]], axis=-1), ws[k], bs[k])
                s = _sigmoid(gates)
                # c <- sigmoid(f) c + sigmoid(i) tanh(g);  h <- sigmoid(o) tanh(c)
                c[k] = s[..., hid : 2 * hid] * c[k] + s[..., :hid] * np.tanh(
                    gates[..., 2 * hid : 3 * hid]
                )
                inp = h[k] = s[..., 3 * hid :] * np.tanh(c[k])
            # y = W2 relu(W1 h + b1) + b2                                     (n_batch, n_joint)
            y = _affine(np.maximum(_affine(inp, w1, b1), 0.0), w2, b2).reshape(n_batch, n_joint)
            if cfg.residual:
                y = y + x[:, -n_joint:]
            if prior is not None:
                y = y + prior[t]
            # omega[k+1] = y std + mean, then the speed bound and the end stops
            th, om = integrate_np(th, y * y_std + y_mean, dt=dt, limits=limits)
            th_out[:, warmup + t] = th
            om_out[:, warmup + t] = om
    return th_out, om_out


def rollout_episodes_numpy(
    sur: Surrogate, episodes: Sequence[Episode], *, max_steps: int | None = None
) -> list[EpisodeRollout]:
    """:func:`~.rollout.rollout_episodes` (measured reference, the model's own warm-up)
    stepped by :func:`rollout_numpy`: every episode in one batch, shorter ones padded."""
    if not episodes:
        return []
    thetas, _, th0, pad_u = batch_episodes(
        episodes, reference="measured", warmup=sur.window, max_steps=max_steps
    )
    th_hat, om_hat = rollout_numpy(sur, th0, pad_u, warmup=sur.window)
    return episode_rollouts(episodes, thetas, th_hat, om_hat, sur=sur, warmup=sur.window)
