"""The plain-loop reference rollout: what every batched or stateful free run is tested against.

:func:`rollout_reference` free-runs ONE episode one step at a time, with a Python-list
window and NumPy features, under the convention of :mod:`.rollout` (the features of sample
``k`` predict ``omega[k+1]``; ``theta[k+1] = theta[k] + T_s * omega_hat[k+1]``).  Given a
list of seed-ensemble members it steps each in its own normalisation and averages their
omega: the reference of a merged ensemble (:func:`.ensemble.merge`).  Joints on a static map
in parallel (``norm.own``) run the map's own NumPy loop beside the network's free run.  It
is slow on purpose and runs none of the torch paths it checks: it encodes with the NumPy
features (:mod:`.features_np`) and integrates with :func:`.angles.integrate_np`, pieces it
shares with the NumPy loop (:mod:`.numpy_loop`), not with the batched rollout.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Literal

import numpy as np
import torch

from .angles import integrate_np, omega_in_np
from .ensemble import check_members
from .envelope import with_end_stops
from .model import Surrogate
from .own_angles import OWN_FIELDS

Mode = Literal["windowed", "stateful"]


@torch.no_grad()
def rollout_reference(
    sur: Surrogate | Sequence[Surrogate],
    theta: np.ndarray,
    u: np.ndarray,
    *,
    warmup: int | None = None,
    mode: Mode | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Plain-loop reference rollout of ONE sequence, one step at a time.

    Args:
        sur: the surrogate, or the members of a seed ensemble: each member is stepped on its
            own, in its own normalisation, and the members' omega is averaged in NumPy before
            the angle is integrated (the oracle of :func:`.ensemble.merge`).
        theta: (>= warmup, n_joint) recorded angles [rad].
        u: (n_step, n_u) recorded commands (with exogenous inputs).

    Returns:
        ``theta_hat``, ``omega_hat``: (n_step, n_joint), as :func:`rollout`.
    """
    surs = [sur] if isinstance(sur, Surrogate) else list(sur)
    if len(surs) > 1:
        check_members(surs)
    ref = surs[0]
    if ref.norm.own is not None:
        return _parallel_reference(surs, theta, u, warmup=warmup, mode=mode)
    w = ref.window
    warmup = w if warmup is None else int(warmup)
    mode = mode or ref.mode
    spec = ref.spec
    n_step, n_joint = u.shape[0], spec.n_joint
    theta_hat = [np.asarray(theta[k], dtype=np.float64) for k in range(warmup)]
    omega_hat = [np.full(n_joint, np.nan) for _ in range(warmup)]
    limits = ref.limits_np()
    windows: list[list[np.ndarray]] = [[] for _ in surs]
    states = [s.net.init_state(1) if mode == "stateful" else None for s in surs]
    zs = ref.norm.play_from_rest_np(u, spec)  # commands only: independent of the loop
    w_rec = omega_in_np(np.asarray(theta[:warmup], dtype=np.float64), spec)  # recorded velocity
    for k in range(n_step - 1):
        omegas = []
        w_k = w_rec[k] if k < warmup else omega_hat[k]  # the velocity feature of sample k
        for m, s in enumerate(surs):
            x = s.norm.encode_np(theta_hat[k], u[k], spec, None if zs is None else zs[k], w_k)
            t = {"dtype": s.dtype, "device": s.device}
            if mode == "windowed":
                window = windows[m]
                window.append(x)
                if len(window) > w:
                    window.pop(0)
                if k + 1 < warmup:
                    continue
                while len(window) < w:  # only if warmup < window
                    window.insert(0, window[0])
                y = s.net(torch.tensor(np.array(window)[None], **t))[0]
            else:
                y, states[m] = s.net.step(torch.tensor(x[None], **t), states[m])
                y = y[0]
                if k + 1 < warmup:
                    continue
            y_std = s.norm.y_std.double().cpu().numpy()
            y_mean = s.norm.y_mean.double().cpu().numpy()
            omegas.append(y.double().cpu().numpy() * y_std + y_mean)
        if k + 1 < warmup:
            continue
        omega = np.mean(omegas, axis=0)
        theta_next, omega = integrate_np(theta_hat[k], omega, dt=spec.dt, limits=limits)
        omega_hat.append(omega)
        theta_hat.append(theta_next)
    return np.array(theta_hat), np.array(omega_hat)


def _parallel_reference(
    surs: Sequence[Surrogate],
    theta: np.ndarray,
    u: np.ndarray,
    *,
    warmup: int | None,
    mode: Mode | None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rollout_reference` of joints on a static map in parallel (``norm.own``): the
    network's own free run (the surrogates without the map) on the other joints, and on the
    map joints the map's free run, a NumPy loop of its own::

        omega[k+1] = s(u[k - d]),  theta[k+1] = theta[k] + T_s omega[k+1]   (end stops)

    with the command before the first sample at the command centre (rest), within the
    model's end stops; the network runs within its own (``own.theta_min``, if set)."""
    ref = surs[0]
    own = ref.norm.own
    assert own is not None
    spec_net = ref.spec
    if own.theta_min is not None and own.theta_max is not None:
        every = [True] * ref.spec.n_joint
        lo, hi = own.theta_min.cpu().numpy(), own.theta_max.cpu().numpy()
        spec_net = with_end_stops(ref.spec, lo, hi, joints=every)
    nets = [replace(s, spec=spec_net, norm=s.norm.with_own(None)) for s in surs]
    th_net, om_net = rollout_reference(nets, theta, u, warmup=warmup, mode=mode)
    warmup = ref.window if warmup is None else int(warmup)
    spec = ref.spec
    n_joint = spec.n_joint
    center = np.array([c.u_center for c in spec.u_specs[:n_joint]])
    a_pos, a_neg, k_pos, k_neg = (getattr(own, k).double().cpu().numpy() for k in OWN_FIELDS)
    th, om = th_net.copy(), om_net.copy()
    limits = ref.limits_np()
    theta_map = np.asarray(theta[warmup - 1], dtype=np.float64)
    for k in range(warmup - 1, u.shape[0] - 1):
        u_d = np.array(
            [u[k - d, j] if k >= d else center[j] for j, d in enumerate(own.delay)],
            dtype=np.float64,
        )
        # s_j(u) = k_pos max(u - a_pos, 0) - k_neg max(a_neg - u, 0)
        s = k_pos * np.maximum(u_d - a_pos, 0.0) - k_neg * np.maximum(a_neg - u_d, 0.0)
        theta_map, w_map = integrate_np(theta_map, s, dt=spec.dt, limits=limits)
        th[k + 1, list(own.own)] = theta_map[list(own.own)]
        om[k + 1, list(own.own)] = w_map[list(own.own)]
    return th, om
