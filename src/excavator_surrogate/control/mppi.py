"""Model-predictive path integral control (MPPI) through a batched predictor.

At every control step the planner samples ``K`` perturbations of its current mean command
sequence (``N`` samples long), rolls all ``K`` candidates out in ONE batched call of a
:class:`~.predict.Predictor` (the surrogate, or the plant model itself as an oracle), scores
them against the reference over the horizon and moves the mean to the cost-weighted average
of the candidates (Williams et al., "Information theoretic MPC", 2017).  The first
``replan`` commands of the mean are applied, then the mean is shifted (warm start).

Cost of a candidate (``e``: angle error, periodic joints wrapped, in rad; ``ũ`` the command
in units of each joint's half range)::

    S = Σ_n Σ_j w_j e[n, j]² / N  +  smooth · Σ_n Σ_j (ũ[n, j] - ũ[n-1, j])² / N

With a risk weight ``r > 0`` (a merged seed ensemble, :meth:`~.predict.SurrogatePredictor.predict_risk`)
the cost adds what the surrogate does not know, from the same batched rollout (``σ`` the
members' angle spread, ``f[n]`` = 1 where step ``n`` is flagged out of distribution)::

    S += r · ( Σ_n Σ_j w_j σ[n, j]² / N  +  ood_penalty · Σ_n f[n] / N )

``σ²`` is in the units of the squared tracking error, so ``r = 1`` prices the members'
disagreement like an error of that size.  ``r = 0`` (default) is the plain planner.

Weights ``exp(-(S - S_min) / λ)`` with the temperature relative to the batch's spread,
``λ = temperature · (mean(S) - S_min)``: the update then does not depend on the units of
the cost.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..config import check_types
from ..errors import ConfigError, ExsurError
from ..spec import MachineSpec
from .predict import Predictor


@dataclass(frozen=True)
class MPPIConfig:
    """Options of :class:`MPPI`."""

    n_sample: int = 256
    """K: candidate command sequences per control step (one batched rollout)."""
    n_horizon: int = 20
    """N: horizon [samples of the machine's rate] (20 = 1 s at 20 Hz)."""
    replan: int = 2
    """Machine samples per control step: the first ``replan`` commands of the plan are applied
    (2 at 20 Hz = a 10 Hz planner)."""
    sigma: float = 0.35
    """Standard deviation of the command noise [fraction of each joint's half range]."""
    beta: float = 0.9
    """AR(1) correlation of the noise from one sample to the next (smooth candidates; 0.9
    rather than 0.8: through the demo surrogate the swing stayed within 1.25x of the oracle on
    15 of 15 runs instead of 10, and the oracle's swing RMSE varied less over seeds)."""
    temperature: float = 0.1
    """λ relative to the batch's cost spread ``mean(S) - min(S)`` (smaller: greedier)."""
    smooth: float = 0.01
    """Weight of the squared command change per sample (in half ranges); finite, >= 0."""
    joint_weights: tuple[float, ...] = ()
    """Per-joint weights ``w_j`` of the squared angle error; empty = 1 for every joint."""
    seed: int = 0
    """Seed of the noise generator."""
    risk: float = 0.0
    """Weight of the surrogate's uncertainty in the cost (member spread and out-of-distribution steps); 0: off."""
    ood_penalty: float = 1.0
    """Cost per unit risk of a candidate flagged out of distribution on every step [rad², as the squared error]."""

    def __post_init__(self) -> None:
        check_types(self, "mppi")  # a wrong type: one line, not a failed comparison below
        if self.n_sample < 2 or self.n_horizon < 1 or not 1 <= self.replan <= self.n_horizon:
            raise ConfigError(
                "mppi: need n_sample >= 2, n_horizon >= 1 and 1 <= replan <= n_horizon, got "
                f"{self.n_sample}, {self.n_horizon}, {self.replan}"
            )
        if not self.sigma > 0 or not 0 <= self.beta < 1 or not self.temperature > 0:
            raise ConfigError(
                f"mppi: need sigma > 0, 0 <= beta < 1, temperature > 0, got {self.sigma}, {self.beta}, {self.temperature}"
            )
        if not (self.risk >= 0 and math.isfinite(self.risk)) or not (
            self.ood_penalty >= 0 and math.isfinite(self.ood_penalty)
        ):
            raise ConfigError(
                "mppi: need finite risk >= 0 and ood_penalty >= 0, got "
                f"{self.risk}, {self.ood_penalty}"
            )
        if not (self.smooth >= 0 and math.isfinite(self.smooth)):  # < 0 rewards jerky commands
            raise ConfigError(f"mppi.smooth: need a finite weight >= 0, got {self.smooth}")


@dataclass
class PlanStats:
    """Per control step bookkeeping of :class:`MPPI`."""

    plan_s: list[float] = field(default_factory=list)
    """Wall time of each control step (sampling, batched rollout, update) [s]."""
    cost: list[float] = field(default_factory=list)
    """Lowest candidate cost of each control step."""
    ood: list[float] = field(default_factory=list)
    """With ``risk > 0``: share of out-of-distribution steps in the weighted candidates."""


class MPPI:
    """MPPI tracking controller of joint-angle references.

    Args:
        predictor: the batched model (``n_sample`` rows per call).
        config: options.

    Use: ``reset(theta0)``, then per machine sample ``k`` call ``act(k, theta_ref)`` for the
    command and ``observe(u, theta)`` with the measurement after it.
    """

    def __init__(self, predictor: Predictor, config: MPPIConfig | None = None) -> None:
        self.cfg = cfg = config or MPPIConfig()
        self.predictor = predictor
        if cfg.risk > 0 and getattr(predictor, "head", None) is None:
            raise ConfigError(
                f"mppi.risk = {cfg.risk:g} needs the surrogate's spread: plan through a merged "
                "seed ensemble (members >= 2); this predictor has none (use risk = 0)"
            )
        spec: MachineSpec = predictor.spec
        self.spec = spec
        n = spec.n_joint
        self.u_center = np.array([j.u_center for j in spec.joints])
        self.u_scale = np.array([j.u_scale for j in spec.joints])
        self.u_min = np.array([j.u_min for j in spec.joints])
        self.u_max = np.array([j.u_max for j in spec.joints])
        self.periodic = np.asarray(spec.periodic, dtype=bool)
        w = np.ones(n) if not cfg.joint_weights else np.asarray(cfg.joint_weights, dtype=float)
        if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ConfigError(
                f"mppi.joint_weights: need {n} finite non-negative weights, got {w.tolist()}"
            )
        self.w = w
        self.rng = np.random.default_rng(cfg.seed)
        # ṽ_rest = (clip(0, u_min, u_max) - u_center) / u_scale: the rest command [half ranges]
        self.v_rest = (np.clip(0.0, self.u_min, self.u_max) - self.u_center) / self.u_scale
        """Rest command (n_joint,) in half ranges around u_center (0 on symmetric ranges)."""
        self.mean = np.repeat(self.v_rest[None], cfg.n_horizon, axis=0)
        """Current plan (n_horizon, n_joint) in half ranges around u_center."""
        self.u_prev = self.v_rest.copy()
        self._plan = np.zeros((cfg.replan, n))
        self.stats = PlanStats()

    def reset(self, theta0: np.ndarray) -> None:
        """Start at rest at ``theta0`` (n_joint,) [rad]: the plan holds the rest command (0
        clipped into each joint's range), fresh noise generator."""
        self.predictor.reset(theta0)
        self._start(np.zeros_like(self.u_prev))

    def reset_history(self, theta_hist: np.ndarray, u_hist: np.ndarray) -> None:
        """Take over mid-motion after the recorded ``theta_hist`` (n_hist, n_joint) [rad] and
        commands ``u_hist`` (n_hist - 1, n_u): the predictor warms up on them, the plan holds
        the rest command, and the smoothness cost starts from the last recorded command."""
        self.predictor.reset_history(theta_hist, u_hist)
        self._start(np.asarray(u_hist, dtype=np.float64)[-1, : self.u_prev.shape[-1]])

    def _start(self, u_last: np.ndarray) -> None:
        """A plan at the rest command (not the range's centre: on an asymmetric range such as
        [-200, 1000] that is 400 while asked to hold still), fresh noise generator, no
        statistics; the smoothness cost starts from the command ``u_last`` (n_joint,)
        [command units], clipped into the range."""
        self.rng = np.random.default_rng(self.cfg.seed)
        self.mean[:] = self.v_rest
        self.u_prev = (np.clip(u_last, self.u_min, self.u_max) - self.u_center) / self.u_scale
        self.stats = PlanStats()

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        """Forward the applied command and the measurement to the predictor."""
        self.predictor.observe(u, theta)

    def noise(self) -> np.ndarray:
        """AR(1)-correlated perturbations (n_sample, n_horizon, n_joint) [half ranges]; row 0
        is zero (the unperturbed mean is always a candidate)."""
        cfg = self.cfg
        w = self.rng.standard_normal((cfg.n_sample, cfg.n_horizon, self.spec.n_joint))
        eps = np.empty_like(w)
        eps[:, 0] = w[:, 0]
        a = math.sqrt(1.0 - cfg.beta**2)
        for k in range(1, cfg.n_horizon):
            eps[:, k] = cfg.beta * eps[:, k - 1] + a * w[:, k]
        eps *= cfg.sigma
        eps[0] = 0.0
        return eps

    def cost(self, theta: np.ndarray, theta_ref: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Costs (n_sample,) of predicted angles ``theta`` (n_sample, N, n_joint) against
        ``theta_ref`` (N, n_joint) [rad] with candidate commands ``v`` [half ranges]."""
        e = theta - theta_ref[None]
        if self.periodic.any():
            e[..., self.periodic] = (e[..., self.periodic] + math.pi) % (2 * math.pi) - math.pi
        track = np.einsum("knj,j->k", e * e, self.w) / e.shape[1]
        dv = np.diff(
            np.concatenate([np.broadcast_to(self.u_prev, v[:, :1].shape), v], axis=1), axis=1
        )
        return track + self.cfg.smooth * (dv * dv).sum(axis=(1, 2)) / v.shape[1]

    def risk_cost(self, spread: np.ndarray, ood: np.ndarray | None) -> np.ndarray:
        """Uncertainty costs (n_sample,) per unit risk of the members' angle spread
        ``spread`` (n_sample, N, n_joint) [rad] and the flags ``ood`` (n_sample, N) (None: none)."""
        s = np.einsum("knj,j->k", spread * spread, self.w) / spread.shape[1]
        if ood is not None:
            s = s + self.cfg.ood_penalty * ood.mean(axis=1)
        return s

    def check_reference(self, theta_ref: np.ndarray, *, exact: bool, k: int | None = None) -> None:
        """Refuse a reference ``theta_ref`` [rad] that cannot score the candidates: not
        (n_horizon, n_joint) (``exact``) or (>= n_horizon, n_joint), or a non-finite value among
        its first n_horizon rows (named by row and joint; with ``k``, also by machine sample)."""
        n, nj = self.cfg.n_horizon, self.spec.n_joint
        rows = "" if exact else ">= "
        if (
            theta_ref.ndim != 2
            or theta_ref.shape[1] != nj
            or not (theta_ref.shape[0] == n if exact else theta_ref.shape[0] >= n)
        ):
            raise ConfigError(
                f"mppi: theta_ref must be ({rows}n_horizon = {n}, n_joint = {nj}) [rad], got "
                f"shape {theta_ref.shape}"
            )
        bad = np.argwhere(~np.isfinite(theta_ref[:n]))
        if len(bad):
            r, j = (int(x) for x in bad[0])
            at = "" if k is None else f" (machine sample {k + 1 + r})"
            raise ConfigError(
                f"mppi: theta_ref row {r}{at}, joint {j} ({self.spec.names[j]}) is "
                f"{theta_ref[r, j]}: the reference must be finite over the horizon; fill or cut "
                "its gap"
            )

    def plan(self, theta_ref: np.ndarray) -> np.ndarray:
        """One control step: returns the next ``replan`` commands (replan, n_joint) [command
        units] for the reference ``theta_ref`` (n_horizon, n_joint) of samples k+1..k+N.

        Raises :class:`ConfigError` for a reference of another shape or with a non-finite
        value, :class:`ExsurError` if no candidate's predicted cost is finite (the plan is
        then left as it was)."""
        theta_ref = np.asarray(theta_ref, dtype=np.float64)
        self.check_reference(theta_ref, exact=True)
        return self._replan(theta_ref)

    def _replan(self, theta_ref: np.ndarray) -> np.ndarray:
        """:meth:`plan` for a reference ``theta_ref`` (n_horizon, n_joint) [rad] already
        checked (:meth:`check_reference`)."""
        t0 = time.perf_counter()
        cfg = self.cfg
        lo = (self.u_min - self.u_center) / self.u_scale
        hi = (self.u_max - self.u_center) / self.u_scale
        v = np.clip(self.mean[None] + self.noise(), lo, hi)  # (K, N, J) half ranges
        u = v * self.u_scale + self.u_center
        ood = None
        if cfg.risk > 0:
            theta, spread, ood = self.predictor.predict_risk(u)  # type: ignore[attr-defined]
            s = self.cost(theta, theta_ref, v) + cfg.risk * self.risk_cost(spread, ood)
        else:
            theta = self.predictor.predict(u)
            s = self.cost(theta, theta_ref, v)
        s = np.where(np.isfinite(s), s, np.inf)
        s_min = float(s.min())
        if not math.isfinite(s_min):  # every weight would be NaN, and so the plan from here on
            raise ExsurError(
                f"mppi: no candidate has a finite cost: the predictor's angles are not finite "
                f"for any of the {cfg.n_sample} candidates; check the measured angles and "
                "commands it was given"
            )
        spread = float(np.mean(s[np.isfinite(s)]) - s_min)
        lam = cfg.temperature * max(spread, 1e-12)
        wts = np.exp(-(s - s_min) / lam)
        wts /= wts.sum()
        if ood is not None:
            self.stats.ood.append(float(wts @ ood.mean(axis=1)))
        self.mean = np.einsum("k,knj->nj", wts, v)
        out = self.mean[: cfg.replan].copy()
        self.u_prev = out[-1].copy()
        self.mean = np.concatenate(
            [self.mean[cfg.replan :], np.repeat(self.mean[-1:], cfg.replan, axis=0)]
        )
        self.stats.plan_s.append(time.perf_counter() - t0)
        self.stats.cost.append(s_min)
        return out * self.u_scale + self.u_center

    def act(self, k: int, theta_ref: np.ndarray) -> np.ndarray:
        """Command (n_joint,) [command units] at machine sample ``k`` (``k = 0, 1, ...`` since
        :meth:`reset`); plans every ``replan`` samples.  ``theta_ref``: (>= n_horizon,
        n_joint) reference of samples k+1..k+N (padded by the caller past the end)."""
        r = k % self.cfg.replan
        if r == 0:
            theta_ref = np.asarray(theta_ref, dtype=np.float64)
            self.check_reference(theta_ref, exact=False, k=k)  # covers the first n_horizon rows
            self._plan = self._replan(theta_ref[: self.cfg.n_horizon])
        return self._plan[r]
