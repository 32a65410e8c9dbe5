"""The vectorised filter kernels behind :func:`~.kalman.fuse`: adaptive Kalman filters over
time-major lanes, and the detection they share.

Arrays are ``(n_step, n_lane)`` (one lane per batch row and joint); the loop runs over time
only, and the 2x2 / 3x3 matrix algebra is written out in closed form per element, the
equation as the comment above each block (filterpy style).  The methods, the state models
and the detection tests are described in :mod:`.kalman`; :mod:`.reference` is the plain
per-sample loop these kernels reproduce bit for bit.

- :func:`forward2`: the two-state filters (``paper``'s constant velocity, ``gyro``'s angle
  and bias), optionally storing what the smoother needs;
- :func:`rts2`: the Rauch-Tung-Striebel smoother over a stored :func:`forward2` pass;
- :func:`forward3`: the three-state filter with the gyro as a second measurement (``gyro3``);
- :class:`_Detector`: the jump and consistency tests and the lock-out guard.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from .config import CleanConfig, max_untrusted_steps

_RTS_CHUNK = 4096
"""Time steps per block when computing smoother gains (bounds memory)."""


def integrate_gyro(omega: np.ndarray, dt: float) -> np.ndarray:
    """``G_t = dt * sum_{j=1..t} omega_j`` along axis 0 (``G_0 = 0``); same shape as ``omega``."""
    G = np.zeros_like(omega, dtype=np.float64)
    if omega.shape[0] > 1:
        np.cumsum(dt * omega[1:], axis=0, out=G[1:])
    return G


def _model_params(config: CleanConfig, dt: float, model: str) -> tuple[float, float, float, float]:
    """``(a, q0, q1, p0_1)`` of a two-state model: A = [[1, a], [0, 1]], Q = diag(q0, q1)."""
    if model == "cv":
        return dt, config.q_theta * dt, config.q_omega * dt, config.p0_omega
    if model == "gyro":
        return (
            -dt,
            config.q_theta * dt + dt * dt * config.r_gyro,
            config.q_bias * dt,
            config.p0_bias,
        )
    raise ValueError(f"unknown two-state model {model!r}")


class _Detector:
    """Per-step jump and consistency tests and the lock-out guard, shared by the filters.

    Holds the time-major work arrays: ``D_t = z_t - G_t`` (raw angle minus integrated gyro),
    ``E_t = theta_hat_t - G_t`` (fused angle minus integrated gyro, written by the filter),
    the flags ``C`` and, for ``jump_ref="raw"``, the precomputed jump test.
    """

    def __init__(self, z: np.ndarray, g: np.ndarray, *, dt: float, config: CleanConfig) -> None:
        n_step, n_lane = z.shape
        self.G = integrate_gyro(g, dt)
        self.D = z - self.G
        self.E = np.empty((n_step, n_lane))
        self.C = np.empty((n_step, n_lane), dtype=bool)
        self.C[0] = True
        self.raw_jump = config.jump_ref == "raw"
        if self.raw_jump:
            # delta_t = |theta_t - theta_{t-1}| > tau_jump  (needs no filter state: precomputed)
            self.J = np.zeros((n_step, n_lane), dtype=bool)
            self.J[1:] = np.abs(z[1:] - z[:-1]) > config.tau_jump
        self.tau_jump = config.tau_jump
        self.tau2 = config.tau_cons * config.tau_cons
        self.w = config.cons_window
        self.anchors = config.cons_mode == "anchors"
        self.max_run = max_untrusted_steps(config, dt, n_step)
        self.next_check = self.max_run + 1
        self.r_tab = np.array([config.r_untrust, config.r_trust])

    def flags(self, t: int, y: np.ndarray) -> np.ndarray:
        """c_t before the guard (a view of ``C[t]``); ``y`` is the innovation ``z_t - theta_prior``."""
        # jump: delta = |z_t - z_{t-1}| (raw) or |z_t - theta_prior| (prior)
        jump = self.J[t] if self.raw_jump else np.abs(y) > self.tau_jump
        # consistency: eps^2 = mean over the window of (theta - theta_intg)^2
        lo = t - self.w if t > self.w else 0
        if self.anchors:
            dev = self.D[t] - self.E[lo:t]
        else:
            dev = self.D[lo + 1 : t + 1] - self.E[lo]
        ok = np.add.reduce(dev * dev, axis=0) < (t - lo) * self.tau2
        # c = consistent and not jump
        return np.greater(ok, jump, out=self.C[t])

    def stale(self, t: int) -> np.ndarray | None:
        """Lanes whose run of untrusted samples would exceed ``max_run`` at ``t`` (then ``C[t]``
        is set True for them), or None.  Amortised: checks only when a lane can be stale."""
        if t < self.next_check:
            return None
        m = self.max_run
        # rows t, t-1, ..., t-m: a lane is stale if none is trusted
        recent = self.C[t - m : t + 1][::-1]
        bad = ~recent.any(axis=0)
        back = np.where(bad, 0, recent.argmax(axis=0))  # samples since the last trusted one
        # the earliest step at which some lane may become stale
        self.next_check = t + m + 1 - int(back.max())
        if not bad.any():
            return None
        self.C[t][bad] = True
        return bad


def forward2(
    z: np.ndarray,
    g: np.ndarray,
    *,
    dt: float,
    config: CleanConfig,
    model: Literal["cv", "gyro"],
    store: bool = False,
) -> dict[str, np.ndarray]:
    """Adaptive two-state Kalman filter over time-major lanes.

    Args:
        z: (n_step, n_lane) measured angles [rad].
        g: (n_step, n_lane) measured gyro velocities [rad/s].
        dt: Ts [s].
        config: parameters.
        model: ``cv`` (paper: s = [theta, omega]) or ``gyro`` (s = [theta, b], gyro input).
        store: also return the posterior covariance per step (for smoothing).

    Returns:
        dict with ``theta`` (n_step, n_lane) posterior angle, ``x1`` second state
        (omega or bias), ``trusted`` bool flags, and with ``store`` ``p00``, ``p01``, ``p11``.
    """
    cfg = config
    n_step, n_lane = z.shape
    a, q0, q1, p0_1 = _model_params(cfg, dt, model)
    U = dt * g if model == "gyro" else None
    det = _Detector(z, g, dt=dt, config=cfg)
    G, E, r_tab = det.G, det.E, det.r_tab
    TH = np.empty((n_step, n_lane))
    X1 = np.empty((n_step, n_lane))
    if store:
        P00, P01, P11 = (np.empty((n_step, n_lane)) for _ in range(3))
    else:  # scratch rows, overwritten every step
        P00, P01, P11 = (np.empty((2, n_lane)) for _ in range(3))

    # s_0 = [z_0, omega_meas_0] (cv) or [z_0, 0] (gyro);  P_0 = diag(R_trust, p0)
    x0 = TH[0]
    x0[:] = z[0]
    x1 = X1[0]
    x1[:] = g[0] if model == "cv" else 0.0
    p00, p01, p11 = P00[0], P01[0], P11[0]
    p00[:], p01[:], p11[:] = cfg.r_trust, 0.0, p0_1
    np.subtract(x0, G[0], out=E[0])

    for t in range(1, n_step):
        r = t if store else t & 1
        # x = A x + B u
        x0 = x0 + a * x1
        if U is not None:
            x0 += U[t]
        # P = A P A' + Q
        p01n = p01 + a * p11
        p00 = p00 + a * (p01 + p01n) + q0
        p01 = p01n
        p11 = p11 + q1

        zt = z[t]
        # y = z - H x
        y = zt - x0
        c = det.flags(t, y)
        # R = R_trust if c else R_untrust
        R = r_tab.take(c.view(np.uint8))
        # S = H P H' + R
        s = p00 + R
        # K = P H' / S
        k0 = p00 / s
        k1 = p01 / s
        # x = x + K y
        x0 = np.add(x0, k0 * y, out=TH[t])
        x1 = np.add(x1, k1 * y, out=X1[t])
        # P = (I - K H) P
        p11 = np.subtract(p11, k1 * p01, out=P11[r])
        m = 1.0 - k0
        p00 = np.multiply(m, p00, out=P00[r])
        p01 = np.multiply(m, p01, out=P01[r])

        # lock-out guard: untrusted for max_run samples -> re-anchor the angle at z_t
        stale = det.stale(t)
        if stale is not None:
            x0[stale] = zt[stale]
            p00[stale] = cfg.r_trust
            p01[stale] = 0.0
        np.subtract(x0, G[t], out=E[t])

    out = {"theta": TH, "x1": X1, "trusted": det.C}
    if store:
        out.update(p00=P00, p01=P01, p11=P11)
    return out


def rts2(
    fwd: dict[str, np.ndarray],
    g: np.ndarray,
    *,
    dt: float,
    config: CleanConfig,
    model: Literal["cv", "gyro"],
    n_valid: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel smoother (means) over a stored :func:`forward2` pass.

    Args:
        fwd: output of ``forward2(..., store=True)``.
        g: (n_step, n_lane) gyro velocities [rad/s] (the control input of the ``gyro`` model).
        dt: Ts [s].
        config: the parameters used in the forward pass.
        model: the forward pass's model.
        n_valid: (n_lane,) valid samples per lane; smoothing starts at each lane's last
            valid sample (padded samples keep their filtered values).

    Returns:
        ``(theta_s, x1_s)``, each (n_step, n_lane).
    """
    a, q0, q1, _ = _model_params(config, dt, model)
    X0, X1 = fwd["theta"], fwd["x1"]
    P00, P01, P11 = fwd["p00"], fwd["p01"], fwd["p11"]
    n_step, n_lane = X0.shape
    nv = np.full(n_lane, n_step) if n_valid is None else np.asarray(n_valid)
    XS0 = np.empty_like(X0)
    XS1 = np.empty_like(X1)
    XS0[-1], XS1[-1] = X0[-1], X1[-1]
    xs = np.stack([X0[-1], X1[-1]])
    hi = n_step - 1
    while hi > 0:
        lo = max(0, hi - _RTS_CHUNK)
        sl = slice(lo, hi)
        p00, p01, p11 = P00[sl], P01[sl], P11[sl]
        # P- = A P A' + Q   (prediction of step k+1 from k)
        pp01 = p01 + a * p11
        pp00 = p00 + a * (p01 + pp01) + q0
        pp11 = p11 + q1
        # C = P A' inv(P-),   P A' = [[p00 + a p01, p01], [p01 + a p11, p11]]
        det = pp00 * pp11 - pp01 * pp01
        b00 = p00 + a * p01
        b10 = pp01  # p01 + a p11
        c00 = (b00 * pp11 - p01 * pp01) / det
        c01 = (p01 * pp00 - b00 * pp01) / det
        c10 = (b10 * pp11 - p11 * pp01) / det
        c11 = (p11 * pp00 - b10 * pp01) / det
        # x-_{k+1} = A x_k + B u_{k+1}
        xp0 = X0[sl] + a * X1[sl]
        if model == "gyro":
            xp0 = xp0 + dt * g[lo + 1 : hi + 1]
        # lanes past their last valid sample: no smoothing (C = 0)
        inert = np.arange(lo, hi)[:, None] >= (nv[None, :] - 1)
        if inert.any():
            for cc in (c00, c01, c10, c11):
                cc[inert] = 0.0
        # stacked per step: X[i] = [x0, x1], XP[i] = x-, CA[i] = C[:, 0], CB[i] = C[:, 1]
        X = np.stack([X0[sl], X1[sl]], axis=1)
        XP = np.stack([xp0, X1[sl]], axis=1)
        CA = np.stack([c00, c10], axis=1)
        CB = np.stack([c01, c11], axis=1)
        XS = np.empty_like(X)
        for i in range(hi - lo - 1, -1, -1):
            # x_s[k] = x[k] + C (x_s[k+1] - x-[k+1])
            d = xs - XP[i]
            xs = np.add(X[i] + CA[i] * d[0], CB[i] * d[1], out=XS[i])
        XS0[sl] = XS[:, 0]
        XS1[sl] = XS[:, 1]
        hi = lo
    return XS0, XS1


def forward3(
    z: np.ndarray,
    g: np.ndarray,
    *,
    dt: float,
    config: CleanConfig,
) -> dict[str, np.ndarray]:
    """Adaptive three-state filter ``s = [theta, omega, b]`` with the gyro as a measurement.

    Args:
        z: (n_step, n_lane) measured angles [rad].
        g: (n_step, n_lane) measured gyro velocities [rad/s].
        dt: Ts [s].
        config: parameters.

    Returns:
        dict with ``theta``, ``omega`` (state), ``bias`` and ``trusted``, each (n_step, n_lane).
    """
    cfg = config
    n_step, n_lane = z.shape
    a = dt
    qw = cfg.q_omega * dt
    # Q for theta_t = theta_{t-1} + Ts omega_t, omega_t = omega_{t-1} + w
    q00 = a * a * qw + cfg.q_theta * dt
    q01 = a * qw
    q11 = qw
    q22 = cfg.q_bias * dt
    rg = cfg.r_gyro
    det = _Detector(z, g, dt=dt, config=cfg)
    G, E, r_tab = det.G, det.E, det.r_tab
    TH = np.empty((n_step, n_lane))
    OM = np.empty((n_step, n_lane))
    B = np.empty((n_step, n_lane))

    # s_0 = [z_0, omega_meas_0, 0];  P_0 = diag(R_trust, p0_omega, p0_bias)
    x0 = TH[0]
    x0[:] = z[0]
    x1 = OM[0]
    x1[:] = g[0]
    x2 = B[0]
    x2[:] = 0.0
    p00 = np.full(n_lane, cfg.r_trust)
    p01 = np.zeros(n_lane)
    p02 = np.zeros(n_lane)
    p11 = np.full(n_lane, cfg.p0_omega)
    p12 = np.zeros(n_lane)
    p22 = np.full(n_lane, cfg.p0_bias)
    np.subtract(x0, G[0], out=E[0])

    for t in range(1, n_step):
        # x = A x,   A = [[1, Ts, 0], [0, 1, 0], [0, 0, 1]]
        x0 = x0 + a * x1
        # P = A P A' + Q
        p01n = p01 + a * p11
        p00 = p00 + a * (p01 + p01n) + q00
        p01 = p01n + q01
        p02 = p02 + a * p12
        p11 = p11 + q11
        p22 = p22 + q22

        # gyro row, h = [0, 1, 1]:  m = h P,  S = h P h' + r_gyro
        m0 = p01 + p02
        m1 = p11 + p12
        m2 = p12 + p22
        s = m1 + m2 + rg
        # K = P h' / S
        k0 = m0 / s
        k1 = m1 / s
        k2 = m2 / s
        # x = x + K (omega_meas - h x)
        y = g[t] - (x1 + x2)
        x0 = x0 + k0 * y
        x1 = x1 + k1 * y
        x2 = x2 + k2 * y
        # P = P - K (h P)
        p00 = p00 - k0 * m0
        p01 = p01 - k0 * m1
        p02 = p02 - k0 * m2
        p11 = p11 - k1 * m1
        p12 = p12 - k1 * m2
        p22 = p22 - k2 * m2

        zt = z[t]
        # angle row, h = [1, 0, 0]:  y = z - x0 (prior already holds this sample's gyro)
        y = zt - x0
        c = det.flags(t, y)
        R = r_tab.take(c.view(np.uint8))
        # S = p00 + R,  K = P[:, 0] / S
        s = p00 + R
        k0 = p00 / s
        k1 = p01 / s
        k2 = p02 / s
        # x = x + K y
        x0 = np.add(x0, k0 * y, out=TH[t])
        x1 = np.add(x1, k1 * y, out=OM[t])
        x2 = np.add(x2, k2 * y, out=B[t])
        # P = (I - K h) P
        p11 = p11 - k1 * p01
        p12 = p12 - k1 * p02
        p22 = p22 - k2 * p02
        m = 1.0 - k0
        p00 = m * p00
        p01 = m * p01
        p02 = m * p02

        stale = det.stale(t)
        if stale is not None:
            x0[stale] = zt[stale]
            p00[stale] = cfg.r_trust
            p01[stale] = 0.0
            p02[stale] = 0.0
        np.subtract(x0, G[t], out=E[t])

    return {"theta": TH, "omega": OM, "bias": B, "trusted": det.C}
