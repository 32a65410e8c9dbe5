"""The structured per-joint baseline: dead zone, direction-dependent gain, pure delay, end stops.

The simplest physical model of a valve-controlled hydraulic joint: its speed is a static
function of its own command a few samples earlier, and its angle stays between the end stops::

    omega_j[t+1] = k_pos,j * max(u_j[t-d_j] - a_pos,j, 0) + k_neg,j * min(u_j[t-d_j] - a_neg,j, 0)
    theta_j[t+1] = clip(theta_j[t] + T_s omega_j[t+1], theta_min,j, theta_max,j)

with a dead zone ``[a_neg, a_pos]`` around zero (``a_neg <= 0 <= a_pos``, command units), a
gain per direction ``k_pos, k_neg >= 0`` [rad/s per command unit] and a delay ``d`` [samples].
It ignores the other joints, the load and any exogenous input.  :func:`fit_structured` fits it
per joint by least squares on the one-step speed of the training split: for every delay
``0..max_delay`` and every dead-zone edge on a grid, the gain is the closed-form least-squares
slope (clipped at 0); the two directions are separable (their regressors never overlap), so
each side's edge is picked on its own; the delay with the smallest total error wins.  The end
stops are the training range (:func:`training_range_spec`).

On logs of machines that drift from day to day, such a model can generalise better than a
network; it is the ``structured`` row of ``bench/real.py``.  It runs in the same free-run
machinery as the ARX baseline (a windowed :class:`~.model.Surrogate` of window ``W``), so
:func:`~excavator_surrogate.evaluate.cbe.evaluate_models` scores it as any model.  It is a
baseline, not a checkpoint: it is not saved.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from ..data.episode import Episode
from ..errors import DataError
from ..spec import MachineSpec
from .angles import omega_target
from .envelope import fill_envelope
from .features import Normalization
from .model import ModelConfig, Surrogate

N_EDGE = 31
"""Dead-zone edges tried per direction (0 to ``max_dead_zone`` of the command range)."""
MAX_DEAD_ZONE = 0.6
"""Largest dead-zone edge tried [fraction of u_max, or of |u_min|]."""
MAX_DELAY_S = 1.0
"""Longest delay tried [s] (also bounded by the window: ``d <= W - 1``)."""


@dataclass(frozen=True)
class JointFit:
    """The fitted model of one joint (command units of the joint, angles in rad)."""

    delay: int
    """Pure delay d [samples]."""
    a_pos: float
    """Upper dead-zone edge (>= 0) [command units]."""
    a_neg: float
    """Lower dead-zone edge (<= 0) [command units]."""
    k_pos: float
    """Gain above the dead zone (>= 0) [rad/s per command unit]."""
    k_neg: float
    """Gain below the dead zone (>= 0) [rad/s per command unit]."""
    rmse: float
    """One-step speed RMSE on the training rows [rad/s]."""

    def speed(self, u: np.ndarray) -> np.ndarray:
        """Static map: speed [rad/s] of (already delayed) commands ``u`` [command units]."""
        u = np.asarray(u, dtype=np.float64)
        return self.k_pos * np.maximum(u - self.a_pos, 0.0) + self.k_neg * np.minimum(
            u - self.a_neg, 0.0
        )


def training_range_spec(spec: MachineSpec, episodes: Sequence[Episode]) -> MachineSpec:
    """``spec`` with end stops at the training data's angle range where it declares none
    (periodic joints get none); the speed bounds are left as declared."""
    out, _ = fill_envelope(spec, episodes, limit_margin=0.0, speed_margin=-1.0)
    return out


def _side_fit(u: np.ndarray, w: np.ndarray, edges: np.ndarray) -> tuple[float, float, float]:
    """Best edge and gain of one direction: rows ``u >= 0`` (the negative side is passed
    sign-flipped), speeds ``w`` (flipped alike), candidate ``edges >= 0``.
    Returns ``(sse, edge, gain)``."""
    if u.size == 0:
        return 0.0, 0.0, 0.0
    v = np.maximum(u[None, :] - edges[:, None], 0.0)  # (n_edge, n_row)
    vv = (v * v).sum(axis=1)
    vw = (v * w[None, :]).sum(axis=1)
    k = np.where(vv > 0, np.maximum(vw / np.maximum(vv, 1e-300), 0.0), 0.0)
    sse = np.maximum((w * w).sum() - 2.0 * k * vw + k * k * vv, 0.0)  # >= 0 despite rounding
    i = int(np.argmin(sse))
    return float(sse[i]), float(edges[i]), float(k[i])


def fit_joint(
    u: Sequence[np.ndarray],
    w: Sequence[np.ndarray],
    *,
    u_min: float,
    u_max: float,
    max_delay: int,
    n_edge: int = N_EDGE,
    max_dead_zone: float = MAX_DEAD_ZONE,
) -> JointFit:
    """Fit one joint on episodes of commands ``u[i]: (n_step,)`` and speeds ``w[i]: (n_step,)``
    (``w[i][t]`` is the speed reached at sample ``t``, i.e. ``(theta[t] - theta[t-1]) / T_s``).

    Every delay uses the same rows (``t >= max_delay + 1``), so their errors compare fairly.
    """
    best: JointFit | None = None
    pos_edges = np.linspace(0.0, max_dead_zone * max(u_max, 0.0), n_edge)
    neg_edges = np.linspace(0.0, max_dead_zone * max(-u_min, 0.0), n_edge)
    n_rows = 0
    for d in range(max_delay + 1):
        us, ws = [], []
        for ui, wi in zip(u, w):
            n = len(ui)
            first = max_delay + 1
            if n <= first:
                continue
            us.append(ui[first - 1 - d : n - 1 - d])  # u[t-1-d] -> w[t]
            ws.append(wi[first:])
        if not us:
            break
        uc, wc = np.concatenate(us), np.concatenate(ws)
        ok = np.isfinite(uc) & np.isfinite(wc)
        uc, wc = uc[ok], wc[ok]
        n_rows = uc.size
        pos = uc >= 0
        sse_p, a_p, k_p = _side_fit(uc[pos], wc[pos], pos_edges)
        sse_n, a_n, k_n = _side_fit(-uc[~pos], -wc[~pos], neg_edges)
        rmse = float(np.sqrt((sse_p + sse_n) / max(n_rows, 1)))
        if best is None or rmse < best.rmse:
            best = JointFit(delay=d, a_pos=a_p, a_neg=-a_n, k_pos=k_p, k_neg=k_n, rmse=rmse)
    if best is None or n_rows == 0:
        raise DataError(
            None, f"no training episode is longer than the delay search ({max_delay + 1} samples)"
        )
    return best


def fit_joints(episodes: Sequence[Episode], spec: MachineSpec, *, max_delay: int) -> list[JointFit]:
    """:func:`fit_joint` for every joint of ``spec`` on ``episodes`` (speeds from the angles)."""
    omegas = [omega_target(e.theta, spec) for e in episodes]
    return [
        fit_joint(
            [e.u[:, j] for e in episodes],
            [om[:, j] for om in omegas],
            u_min=js.u_min,
            u_max=js.u_max,
            max_delay=max_delay,
        )
        for j, js in enumerate(spec.joints)
    ]


class StructuredNet(nn.Module):
    """Windowed network of the structured model: ``(n_batch, W, n_feature)`` normalised feature
    window -> ``(n_batch, n_joint)`` normalised ``omega[t+1]``.  It reads each joint's own command
    ``d_j`` samples before the window's end and applies the static map of :class:`JointFit`."""

    stateful_capable = False

    def __init__(self, fits: Sequence[JointFit], spec: MachineSpec, norm: Normalization) -> None:
        super().__init__()
        self.cols = [spec.n_angle_feature + j for j in range(spec.n_joint)]
        self.delays = [f.delay for f in fits]
        f32 = torch.float32

        def buf(name: str, values: Sequence[float]) -> None:  # parameters: they set device/dtype
            t = torch.tensor(list(values), dtype=f32)
            self.register_parameter(name, nn.Parameter(t, requires_grad=False))

        buf("a_pos", [f.a_pos for f in fits])
        buf("a_neg", [f.a_neg for f in fits])
        buf("k_pos", [f.k_pos for f in fits])
        buf("k_neg", [f.k_neg for f in fits])
        buf("x_mean", [float(norm.x_mean[c]) for c in self.cols])
        buf("x_std", [float(norm.x_std[c]) for c in self.cols])
        buf("u_center", [float(norm.u_center[j]) for j in range(spec.n_joint)])
        buf("u_scale", [float(norm.u_scale[j]) for j in range(spec.n_joint)])
        buf("y_mean", [float(v) for v in norm.y_mean])
        buf("y_std", [float(v) for v in norm.y_std])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x: (n_batch, W, n_feature)`` -> ``(n_batch, n_joint)`` normalised omega."""
        n_win = x.shape[1]
        xs = torch.stack(
            [x[:, n_win - 1 - d, c] for d, c in zip(self.delays, self.cols)], dim=-1
        )  # (n_batch, n_joint) normalised commands u[t-d]
        u = (xs * self.x_std + self.x_mean) * self.u_scale + self.u_center
        w = self.k_pos * torch.relu(u - self.a_pos) - self.k_neg * torch.relu(self.a_neg - u)
        return (w - self.y_mean) / self.y_std


def fit_structured(
    episodes: Sequence[Episode],
    *,
    window: int = 30,
    spec: MachineSpec | None = None,
    max_delay_s: float = MAX_DELAY_S,
    end_stops: bool = True,
) -> Surrogate:
    """Fit the structured per-joint baseline on ``episodes`` (training split).

    Args:
        episodes: training episodes (``u: (n_step, n_u)``, ``theta: (n_step, n_joint)``).
        window: W [samples] of the windowed free run (its warm-up); delays up to ``W - 1``.
        spec: machine spec (default: the first episode's).
        max_delay_s: longest delay tried [s].
        end_stops: clip free-run angles to the training range (:func:`training_range_spec`).

    Returns:
        A windowed :class:`Surrogate` named ``structured``; ``metrics["joints"]`` holds each
        joint's :class:`JointFit` as a dict.
    """
    if not episodes:
        raise DataError(None, "no training episodes to fit the structured baseline")
    spec = spec or episodes[0].spec
    rate = spec.rate_hz
    max_delay = int(max(0, min(window - 1, round(max_delay_s * rate))))
    norm = Normalization.fit([e.theta for e in episodes], [e.u for e in episodes], spec)
    fits = fit_joints(episodes, spec, max_delay=max_delay)
    run_spec = training_range_spec(spec, episodes) if end_stops else spec
    cfg = ModelConfig(n_feature=norm.n_feature, n_joint=spec.n_joint, window=window, cell="arx")
    net = StructuredNet(fits, spec, norm).eval()
    joints = {js.name: vars(f).copy() for js, f in zip(spec.joints, fits)}
    return Surrogate(
        net=net,
        spec=run_spec,
        norm=norm,
        model_cfg=cfg,
        mode="windowed",
        train_config={"baseline": "structured", "window": window, "max_delay": max_delay},
        metrics={"joints": joints},
        name="structured",
        end_stops=end_stops,
    )


def max_map_delay(window: int, spec: MachineSpec) -> int:
    """The longest delay [samples] a map inside a network may have: :data:`MAX_DELAY_S`, and
    no more than the window holds (``window - 1``)."""
    return int(max(0, min(window - 1, round(MAX_DELAY_S * spec.rate_hz))))


def fit_prior(
    episodes: Sequence[Episode], spec: MachineSpec, *, max_delay: int = 0
) -> dict[str, list[float]]:
    """Least-squares static map per joint on ``episodes``: dead-zone edges ``a_pos >= 0 >=
    a_neg`` [command units] and gains ``k_pos, k_neg >= 0`` [rad/s per command unit], plus
    ``cols`` the command's column in the features (the spec fixes the layout), each joint's
    ``delay`` [samples] (0 to ``max_delay``, the one-step error's best: ``omega[k+1] =
    s(u[k - d])``), one-step ``rmse`` [rad/s] and ``gain_spread`` (:func:`gain_spread`)
    (keyword arguments of :meth:`~.prior.SpeedPrior.load_fit`, without ``norm``, and ``delay``,
    ``rmse``, ``gain_spread``).  With ``max_delay = 0`` every joint reads its current command."""
    fits = fit_joints(episodes, spec, max_delay=max_delay)
    omegas = [omega_target(e.theta, spec) for e in episodes]
    return {
        "cols": [spec.n_angle_feature + j for j in range(spec.n_joint)],
        "delay": [int(f.delay) for f in fits],
        "a_pos": [f.a_pos for f in fits],
        "a_neg": [f.a_neg for f in fits],
        "k_pos": [f.k_pos for f in fits],
        "k_neg": [f.k_neg for f in fits],
        "rmse": [float(f.rmse) for f in fits],
        "gain_spread": [
            gain_spread(f, [e.u[:, j] for e in episodes], [om[:, j] for om in omegas], spec.rate_hz)
            for j, f in enumerate(fits)
        ],
    }


def joint_fit(fit: Mapping[str, Sequence[float]], j: int) -> JointFit:
    """Joint ``j``'s map as a :class:`JointFit`, from a map in :func:`fit_prior`'s lists (its
    ``rmse`` where the lists keep one, else 0)."""
    return JointFit(
        delay=int(fit["delay"][j]),
        a_pos=float(fit["a_pos"][j]),
        a_neg=float(fit["a_neg"][j]),
        k_pos=float(fit["k_pos"][j]),
        k_neg=float(fit["k_neg"][j]),
        rmse=float(fit["rmse"][j]) if "rmse" in fit else 0.0,
    )


CHUNK_S = 10.0
"""Length of the stretches of log whose own gain :func:`gain_spread` compares [s]."""
MIN_GAIN_SPREAD = 0.01
"""Smallest relative gain spread of a map (a map is never exact)."""


def gain_spread(
    fit: JointFit, u: Sequence[np.ndarray], w: Sequence[np.ndarray], rate: float
) -> float:
    """How much the joint's speed strays from the static map from one stretch of log to the
    next: the relative standard deviation of the stretch-wise least-squares gain.

    The episodes are cut into stretches of :data:`CHUNK_S`; in each stretch ``c`` the gain
    the map would need is ``rho_c = sum_t w[t] s(u[t-1]) / sum_t s(u[t-1])^2`` (1 where the
    map is right); the result is the spread of ``rho`` around 1, each stretch weighted by its
    ``sum s^2`` (how much the map moves the joint there)::

        sigma = sqrt( sum_c S_c (rho_c - 1)^2 / sum_c S_c ),   S_c = sum_t s(u[t-1])^2

    at least :data:`MIN_GAIN_SPREAD`; with fewer than two moving stretches, the one-step
    RMSE relative to the map's RMS speed.  A map joint's ensemble members drive it with gains
    ``1 + sigma z_m`` (:func:`.series.with_map_joints`), so its spread grows with the distance
    the map has moved it: the error of a gain off by a few percent does.

    Args:
        fit: the joint's map (its delay is used).
        u: per episode, the joint's commands ``(n_step,)`` [command units].
        w: per episode, the joint's speeds ``(n_step,)`` [rad/s] (``w[t]`` reached at ``t``).
        rate: sample rate [Hz].
    """
    n = max(2, round(CHUNK_S * rate))
    num, den = [], []
    for ui, wi in zip(u, w):
        s, wt = _aligned(fit, ui, wi)
        for a in range(0, len(s), n):
            num.append(float(np.dot(wt[a : a + n], s[a : a + n])))
            den.append(float(np.dot(s[a : a + n], s[a : a + n])))
    sc, nu = np.asarray(den), np.asarray(num)
    moving = sc > 0
    if int(moving.sum()) >= 2:
        rho = nu[moving] / sc[moving]
        sigma = float(np.sqrt(np.sum(sc[moving] * (rho - 1.0) ** 2) / sc[moving].sum()))
    else:
        rms = float(np.sqrt(sc.sum() / max(1, sum(len(ui) for ui in u))))
        sigma = fit.rmse / rms if rms > 0 else 1.0
    return max(MIN_GAIN_SPREAD, sigma)


def _aligned(fit: JointFit, u: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map's speed ``s[t] = s(u[t - 1 - d])`` beside the speed ``w[t]`` it should reach,
    ``(s, w)`` of one episode, with 0 in both wherever either is not finite."""
    s = fit.speed(u[: len(u) - 1 - fit.delay])
    wt = w[1 + fit.delay :]
    ok = np.isfinite(s) & np.isfinite(wt)
    return np.where(ok, s, 0.0), np.where(ok, wt, 0.0)


def speed_ratio(fit: JointFit, u: Sequence[np.ndarray], w: Sequence[np.ndarray]) -> float:
    """The least-squares scale of the map's speed to the measured one over the episodes (1 where
    the map is right)::

        rho = sum_t w[t] s(u[t-1-d]) / sum_t s(u[t-1-d])^2

    Args:
        fit: the joint's map (its delay is used).
        u: per episode, the joint's commands ``(n_step,)`` [command units].
        w: per episode, its speeds ``(n_step,)`` [rad/s] (``w[t]`` reached at ``t``).

    Returns:
        ``rho``, or 1.0 where the map never moves the joint in these episodes.
    """
    num = den = 0.0
    for ui, wi in zip(u, w):
        s, wt = _aligned(fit, ui, wi)
        num += float(np.dot(wt, s))
        den += float(np.dot(s, s))
    return num / den if den > 0 else 1.0
