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
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import nn

from ..data.episode import Episode
from ..errors import DataError
from ..spec import MachineSpec
from .angles import omega_target
from .envelope import fill_envelope, with_end_stops
from .features import Normalization
from .model import ModelConfig, Surrogate
from .prior import PRIOR_MAP

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
    (keyword arguments of :meth:`SpeedPrior.load_fit`, without ``norm``, and ``delay``,
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
    ``1 + sigma z_m`` (:func:`with_map_joints`), so its spread grows with the distance the map
    has moved it: the error of a gain off by a few percent does.

    Args:
        fit: the joint's map (its delay is used).
        u: per episode, the joint's commands ``(n_step,)`` [command units].
        w: per episode, the joint's speeds ``(n_step,)`` [rad/s] (``w[t]`` reached at ``t``).
        rate: sample rate [Hz].
    """
    n = max(2, round(CHUNK_S * rate))
    num, den = [], []
    for ui, wi in zip(u, w):
        s = fit.speed(ui[: len(ui) - 1 - fit.delay])
        wt = wi[1 + fit.delay :]
        ok = np.isfinite(s) & np.isfinite(wt)
        s, wt = np.where(ok, s, 0.0), np.where(ok, wt, 0.0)
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


def member_offsets(n_member: int) -> torch.Tensor:
    """(n_member,) float64 fixed offsets, evenly spaced, mean 0 and standard deviation 1
    (ddof 1): the members' places in a map joint's gain spread (:func:`with_map_joints`)."""
    z = torch.linspace(-1.0, 1.0, n_member, dtype=torch.float64)
    return z / z.std() if n_member > 1 else z * 0.0


def with_lag_columns(
    norm: Normalization, state: dict[str, torch.Tensor], lags: Sequence[int]
) -> Normalization:
    """``norm`` with delayed-command features ``lags`` (:meth:`.Normalization.with_lags`),
    and the network weights ``state`` (a ``state_dict``, changed in place) given zero weights
    for those columns in their first layer: the network's output does not change (up to the
    order of float sums).  Returns the new normalisation."""
    new = norm.with_lags(lags)
    at, n_joint = new.lag_start, len(new.periodic)  # the delayed commands' columns
    w = state["rnn.weight_ih_l0"]  # (gates, n_feature)
    state["rnn.weight_ih_l0"] = torch.cat([w[:, :at], w.new_zeros(len(w), n_joint), w[:, at:]], 1)
    return new


def with_map_joints(
    sur: Surrogate,
    fit: Mapping[str, Sequence[float]],
    joints: Sequence[bool],
    *,
    lags: Sequence[int] | None = None,
    map_stops: tuple[Sequence[float], Sequence[float]] | None = None,
) -> Surrogate:
    """A copy of ``sur`` whose ``joints`` move by the static map ``fit`` alone (the network's
    output for them is dropped) while the other joints keep the network's output exactly.

    Built with a :class:`SpeedPrior` whose gains are ``fit``'s on ``joints`` and zero
    elsewhere, the head's output rows of ``joints`` zeroed, and ``y_mean / y_std`` added to the
    other rows' bias (the prior subtracts it from every joint)::

        map joint j:    omega_j = y_std (0) + s_j(u)                 = s_j(u)
        other joint j:  omega_j = y_std (head_j + y_mean_j / y_std_j) = the network's omega_j

    A network that already corrects a map (``model_cfg.prior``) keeps it on the other joints
    (its head carries no ``y_mean``, so no bias moves).

    A joint whose map has a delay ``d_j > 0`` (``fit["delay"]``) reads its command ``d_j``
    samples back: the copy's features get the delayed commands (:meth:`.Normalization.with_lags`,
    carried as a delay line in the command state ``z`` by every runtime), and the network's
    first layer gets zero weights for those columns, so the other joints' output is the
    network's (up to the order of float sums).  Without delays the copy's features are the
    network's.  If ``sur`` already reads delayed commands, a map joint's delay must be its
    feature's, or 0 (the map then reads the current command's column).

    A merged ensemble's member biases are moved alike, and member ``m`` drives a map joint
    with the gain ``1 + sigma_j z_m`` (``metrics["ensemble"]["map_gain_dev"]``, (M, n_joint),
    ``sigma_j`` the map's ``gain_spread``, ``z`` fixed, mean 0 and standard deviation 1 over
    the members): the merged network's own output (their mean) is the map exactly, and the
    members' spread on a map joint is ``sigma_j |s_j(u)|``, integrated in the angle.  The other
    joints still read the map joints' angles, now the map's.

    Args:
        sur: an LSTM/GRU surrogate without a residual head.
        fit: :func:`.structured.fit_prior`'s map (``cols``, ``a_pos``, ``a_neg``, ``k_pos``,
            ``k_neg`` and optionally ``delay`` and ``gain_spread``; per joint).
        joints: (n_joint,) which joints follow the map.
        lags: (n_joint,) the delayed-command features to give a network without them
            (default: each map joint's delay, 0 elsewhere); e.g. those of another network
            this one is to be merged with.
        map_stops: ``(lo, hi)``, (n_joint,) each [rad], the map joints' end stops (the
            copy's spec; +-inf: none), or None: ``sur``'s.  Ignored without end stops.

    Returns:
        A new surrogate (``model_cfg.prior`` set; ``metrics["map_joints"]`` names the joints).

    Raises:
        ValueError: a residual head or ARX; a map delay that the features cannot read.
    """
    if sur.model_cfg.residual or sur.model_cfg.cell == "arx":
        raise ValueError("with_map_joints needs an LSTM/GRU without a residual head")
    pick = torch.tensor([bool(j) for j in joints])
    spec = sur.spec
    n_joint = spec.n_joint
    delay = [int(d) for d in fit.get("delay", [0] * n_joint)]
    old = sur.net.prior if sur.model_cfg.prior else None
    norm = sur.norm
    state = {k: v.detach().clone() for k, v in sur.net.state_dict().items()}
    if not norm.lags:
        want = (
            [int(d) for d in lags]
            if lags is not None
            else [d if p else 0 for d, p in zip(delay, pick.tolist())]
        )
        if any(want):
            norm = with_lag_columns(norm, state, want)
    elif lags is not None and tuple(int(d) for d in lags) != norm.lags:
        raise ValueError(f"with_map_joints: this network already reads the delays {norm.lags}")

    def col(j: int) -> int:
        """The feature column that map joint ``j`` reads."""
        if norm.lags and norm.lags[j] == delay[j]:
            return norm.lag_start + j
        if delay[j] == 0:
            return spec.n_angle_feature + j  # the current command
        raise ValueError(
            f"with_map_joints: joint {spec.names[j]}'s map delay {delay[j]} is not a feature "
            f"of this network (its delays {norm.lags or 'none'})"
        )

    cfg = replace(sur.model_cfg, prior=True, n_feature=norm.n_feature)
    net = type(sur.net)(cfg)
    missing = net.load_state_dict(state, strict=False).missing_keys
    assert all(k.startswith("prior.") for k in missing), missing
    base = {n: getattr(old, n).tolist() for n in PRIOR_MAP} if old is not None else None

    if base is not None:
        keep = base["cols"]
    else:  # gain 0: any column; the delayed or current command, as fit_prior would say
        keep = [
            norm.lag_start + j if norm.lags else spec.n_angle_feature + j for j in range(n_joint)
        ]

    def on(name: str) -> list[float]:
        """The map's ``name`` per joint: ``fit``'s on ``joints``, the old map's (or 0) elsewhere."""
        return [
            float(v) if p else (base[name][j] if base is not None else 0.0)
            for j, (v, p) in enumerate(zip(fit[name], pick.tolist()))
        ]

    net.prior.load_fit(
        cols=[col(j) if p else keep[j] for j, p in enumerate(pick.tolist())],
        a_pos=on("a_pos"),
        a_neg=on("a_neg"),
        k_pos=on("k_pos"),
        k_neg=on("k_neg"),
        norm=norm,
    )
    # a network without a map carries y_mean in its head: the prior now subtracts it
    shift = (
        torch.zeros(n_joint)
        if old is not None
        else (norm.y_mean / norm.y_std).detach().float().cpu()
    )
    last = net.head[2]
    with torch.no_grad():
        last.weight[pick] = 0.0
        last.bias[pick] = 0.0
        last.bias[~pick] += shift.to(last.bias)[~pick]
    metrics = dict(sur.metrics or {})
    ens = metrics.get("ensemble")
    if isinstance(ens, dict) and "member_bias" in ens:
        mb = torch.tensor(ens["member_bias"], dtype=torch.float64)  # (M, n_joint)
        mb[:, pick] = 0.0
        mb[:, ~pick] += shift.double()[~pick]
        metrics["ensemble"] = {**ens, "member_bias": mb.tolist()}
        if "gain_spread" in fit:  # (M, n_joint) each member's gain deviation on the map joints
            sigma = torch.tensor(
                [float(v) if p else 0.0 for v, p in zip(fit["gain_spread"], pick.tolist())],
                dtype=torch.float64,
            )
            dev = member_offsets(mb.shape[0])[:, None] * sigma[None, :]
            if "map_gain_dev" in ens:  # earlier map joints keep theirs
                prev = torch.tensor(ens["map_gain_dev"], dtype=torch.float64)
                dev[:, ~pick] = prev[:, ~pick]
            metrics["ensemble"]["map_gain_dev"] = dev.tolist()
    before = set(metrics.get("map_joints") or [])
    metrics["map_joints"] = [n for n, p in zip(spec.names, pick.tolist()) if p or n in before]
    if map_stops is not None and sur.end_stops:
        spec = with_end_stops(spec, *map_stops, joints=pick.tolist())
    return Surrogate(
        net=net.train(sur.net.training),
        spec=spec,
        norm=norm,
        model_cfg=cfg,
        mode=sur.mode,
        train_config=dict(sur.train_config or {}),
        metrics=metrics,
        name=sur.name,
        end_stops=sur.end_stops,
    )
