"""Plain per-sample, per-joint Python reference of the cleaning filters.

Slow (pure Python floats) and written for clarity: one joint at a time, one sample at a
time.  The vectorised filters in :mod:`.filters` must reproduce it bit for bit (same
operation order); tests and ``bench/clean.py`` use it as the oracle and the speed baseline.
"""

from __future__ import annotations

import numpy as np

from .config import CleanConfig, max_untrusted_steps


def reference_fuse(
    theta: np.ndarray,
    omega: np.ndarray,
    *,
    dt: float,
    config: CleanConfig,
) -> dict[str, np.ndarray]:
    """Run ``config.method`` on one episode with plain loops.

    Args:
        theta: (n_step, n_joint) measured angles [rad].
        omega: (n_step, n_joint) measured gyro velocities [rad/s].
        dt: Ts [s].
        config: parameters.

    Returns:
        dict with ``theta`` (fused angle), ``trusted`` and ``bias`` (gyro-bias estimate; None
        for ``paper``), each (n_step, n_joint).
    """
    theta = np.asarray(theta, dtype=np.float64)
    omega = np.asarray(omega, dtype=np.float64)
    n_step, n_joint = theta.shape
    th_out = np.empty((n_step, n_joint))
    b_out = np.empty((n_step, n_joint))
    tr_out = np.empty((n_step, n_joint), dtype=bool)
    for j in range(n_joint):
        z = theta[:, j].tolist()
        g = omega[:, j].tolist()
        if config.method == "paper":
            th, b, tr, _ = _lane2(z, g, dt, config, "cv")
        elif config.method == "gyro":
            th, b, tr, _ = _lane2(z, g, dt, config, "gyro")
        elif config.method == "gyro3":
            th, b, tr = _lane3(z, g, dt, config)
        else:
            th, x1, tr, covs = _lane2(z, g, dt, config, "gyro")
            th, b = _rts_lane(th, x1, covs, g, dt, config)
        th_out[:, j] = th
        b_out[:, j] = b
        tr_out[:, j] = tr
    return {
        "theta": th_out,
        "trusted": tr_out,
        "bias": None if config.method == "paper" else b_out,
    }


def _detect(
    t: int, z: list[float], D: list[float], E: list[float], prior: float, cfg: CleanConfig
) -> bool:
    """Consistency flag before the guard: not a jump and consistent with the integrated gyro."""
    if cfg.jump_ref == "raw":
        jump = abs(z[t] - z[t - 1]) > cfg.tau_jump
    else:
        jump = abs(z[t] - prior) > cfg.tau_jump
    w = cfg.cons_window
    lo = t - w if t > w else 0
    ss = 0.0
    if cfg.cons_mode == "anchors":
        for i in range(lo, t):  # anchors theta_hat_{t-w} .. theta_hat_{t-1}
            d = D[t] - E[i]
            ss = ss + d * d
    else:
        for k in range(lo + 1, t + 1):  # raw samples t-w+1 .. t against anchor theta_hat_{t-w}
            d = D[k] - E[lo]
            ss = ss + d * d
    ok = ss < (t - lo) * (cfg.tau_cons * cfg.tau_cons)
    return ok and not jump


def _gyro_integral(g: list[float], dt: float) -> list[float]:
    """G_k = dt * (omega_1 + ... + omega_k), G_0 = 0."""
    G = [0.0] * len(g)
    acc = 0.0
    for k in range(1, len(g)):
        acc = acc + dt * g[k]
        G[k] = acc
    return G


def _lane2(
    z: list[float], g: list[float], dt: float, cfg: CleanConfig, model: str
) -> tuple[list[float], list[float], list[bool], list[tuple[float, float, float]]]:
    n = len(z)
    if model == "cv":
        a, q0, q1, p11 = dt, cfg.q_theta * dt, cfg.q_omega * dt, cfg.p0_omega
        x1 = g[0]
    else:
        a, q0, q1, p11 = -dt, cfg.q_theta * dt + dt * dt * cfg.r_gyro, cfg.q_bias * dt, cfg.p0_bias
        x1 = 0.0
    G = _gyro_integral(g, dt)
    D = [z[k] - G[k] for k in range(n)]
    x0, p00, p01 = z[0], cfg.r_trust, 0.0
    E = [x0 - G[0]]
    th, xs1, tr, covs = [x0], [x1], [True], [(p00, p01, p11)]
    max_run = max_untrusted_steps(cfg, dt, n)
    last = 0
    for t in range(1, n):
        # predict
        x0 = x0 + a * x1
        if model == "gyro":
            x0 = x0 + dt * g[t]
        p01n = p01 + a * p11
        p00 = p00 + a * (p01 + p01n) + q0
        p01 = p01n
        p11 = p11 + q1
        # detect
        c = _detect(t, z, D, E, x0, cfg)
        r = cfg.r_trust if c else cfg.r_untrust
        # update
        s = p00 + r
        k0 = p00 / s
        k1 = p01 / s
        y = z[t] - x0
        x0 = x0 + k0 * y
        x1 = x1 + k1 * y
        p11 = p11 - k1 * p01
        m = 1.0 - k0
        p00 = m * p00
        p01 = m * p01
        # lock-out guard
        if not c and (t - last) > max_run:
            x0, p00, p01, c = z[t], cfg.r_trust, 0.0, True
        if c:
            last = t
        th.append(x0)
        xs1.append(x1)
        tr.append(c)
        E.append(x0 - G[t])
        covs.append((p00, p01, p11))
    return th, xs1, tr, covs


def _rts_lane(
    th: list[float],
    x1: list[float],
    covs: list[tuple[float, float, float]],
    g: list[float],
    dt: float,
    cfg: CleanConfig,
) -> tuple[list[float], list[float]]:
    a, q0, q1 = -dt, cfg.q_theta * dt + dt * dt * cfg.r_gyro, cfg.q_bias * dt
    n = len(th)
    out = list(th)
    out1 = list(x1)
    xs0, xs1 = th[-1], x1[-1]
    for k in range(n - 2, -1, -1):
        p00, p01, p11 = covs[k]
        # predicted covariance of step k+1
        pp01 = p01 + a * p11
        pp00 = p00 + a * (p01 + pp01) + q0
        pp11 = p11 + q1
        det = pp00 * pp11 - pp01 * pp01
        b00 = p00 + a * p01
        b10 = pp01
        c00 = (b00 * pp11 - p01 * pp01) / det
        c01 = (p01 * pp00 - b00 * pp01) / det
        c10 = (b10 * pp11 - p11 * pp01) / det
        c11 = (p11 * pp00 - b10 * pp01) / det
        xp0 = th[k] + a * x1[k]
        xp0 = xp0 + dt * g[k + 1]
        xp1 = x1[k]
        d0 = xs0 - xp0
        d1 = xs1 - xp1
        xs0 = th[k] + c00 * d0 + c01 * d1
        xs1 = x1[k] + c10 * d0 + c11 * d1
        out[k] = xs0
        out1[k] = xs1
    return out, out1


def _lane3(
    z: list[float], g: list[float], dt: float, cfg: CleanConfig
) -> tuple[list[float], list[float], list[bool]]:
    n = len(z)
    a = dt
    qw = cfg.q_omega * dt
    q00 = a * a * qw + cfg.q_theta * dt
    q01 = a * qw
    q11 = qw
    q22 = cfg.q_bias * dt
    rg = cfg.r_gyro
    G = _gyro_integral(g, dt)
    D = [z[k] - G[k] for k in range(n)]
    x0, x1, x2 = z[0], g[0], 0.0
    p00, p01, p02, p11, p12, p22 = cfg.r_trust, 0.0, 0.0, cfg.p0_omega, 0.0, cfg.p0_bias
    E = [x0 - G[0]]
    th, bs, tr = [x0], [x2], [True]
    max_run = max_untrusted_steps(cfg, dt, n)
    last = 0
    for t in range(1, n):
        x0 = x0 + a * x1
        p01n = p01 + a * p11
        p00 = p00 + a * (p01 + p01n) + q00
        p01 = p01n + q01
        p02 = p02 + a * p12
        p11 = p11 + q11
        p22 = p22 + q22
        # gyro row
        m0 = p01 + p02
        m1 = p11 + p12
        m2 = p12 + p22
        s = m1 + m2 + rg
        k0, k1, k2 = m0 / s, m1 / s, m2 / s
        y = g[t] - (x1 + x2)
        x0, x1, x2 = x0 + k0 * y, x1 + k1 * y, x2 + k2 * y
        p00, p01, p02 = p00 - k0 * m0, p01 - k0 * m1, p02 - k0 * m2
        p11, p12, p22 = p11 - k1 * m1, p12 - k1 * m2, p22 - k2 * m2
        # detect
        c = _detect(t, z, D, E, x0, cfg)
        r = cfg.r_trust if c else cfg.r_untrust
        # angle row
        s = p00 + r
        k0, k1, k2 = p00 / s, p01 / s, p02 / s
        y = z[t] - x0
        x0, x1, x2 = x0 + k0 * y, x1 + k1 * y, x2 + k2 * y
        p11 = p11 - k1 * p01
        p12 = p12 - k1 * p02
        p22 = p22 - k2 * p02
        m = 1.0 - k0
        p00, p01, p02 = m * p00, m * p01, m * p02
        if not c and (t - last) > max_run:
            x0, p00, p01, p02, c = z[t], cfg.r_trust, 0.0, 0.0, True
        if c:
            last = t
        th.append(x0)
        bs.append(x2)
        tr.append(c)
        E.append(x0 - G[t])
    return th, bs, tr
