"""How sure the surrogate is: ensemble spread, calibrated bands and out-of-distribution flags.

A merged seed ensemble (:func:`.ensemble.merge`) computes every member at every step; the
members' disagreement is its uncertainty.  :func:`predict_with_uncertainty` free-runs a
command sequence and returns, per joint and step:

- the central prediction: the merged network's own free run (what every runtime -- env,
  ONNX, ``rollout`` -- computes);
- the spread: the standard deviation over the members (ddof 1).  By default
  (``design="shared"``) the members' velocities come from the merged network's own run (one
  network call per step, nothing extra to run), and member ``m``'s angle is the central angle
  plus its integrated velocity deviation from the mean, so the angle spread grows with the
  horizon.  ``design="independent"`` lets each member integrate its own angle, as the merged
  network does with the mean: one batch of ``(M + 1) n_batch`` rows, row ``(m, b)``
  following member ``m``'s velocity (``ClosedLoop.follow``).  docs/design.md compares the two;
- bands ``central +/- k_{level, j} spread`` for the calibrated levels (50 % and 90 %), with
  ``k`` fitted per joint on free runs (:func:`.bands.fit_scale`: the level-quantile of
  ``|error| / spread``, per horizon bin for the angle; :func:`.bands.calibrate`: over the
  validation and training runs' free runs together, the validation runs weighing
  ``n_val / (n_val + 6)``, :data:`.bands.RULE`) and stored in the checkpoint
  (``metrics["uncertainty"]``);
- out-of-distribution flags from the training data's :class:`~.coverage.CoverageRecord`
  (``metrics["coverage"]``).

A single network has no members: its spread and bands are ``None`` with a one-line ``note``;
nothing is faked.  :mod:`.bands` builds both records on episodes and scores bands.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import torch

from ..errors import CheckpointError, ConfigError
from .blocks import split
from .coverage import CoverageRecord, ood_flags
from .ensemble import member_head, n_member
from .model import Surrogate
from .rollout import ClosedLoop, rollout

Design = Literal["independent", "shared"]
LEVELS = (0.5, 0.9)
"""Band levels calibrated by default (nominal coverage)."""
NO_MEMBERS = "single network: no uncertainty (train a seed ensemble, members >= 2, for bands)"
"""The note of a surrogate without ensemble members."""


def map_note(sur: Surrogate) -> str | None:
    """The note of an ensemble whose joints follow the static valve map (``metrics
    ["map_joints"]``), or None."""
    on_map = (sur.metrics or {}).get("map_joints") or []
    head = member_head(sur)
    if not on_map or head is None:
        return None
    ens = (sur.metrics or {}).get("ensemble") or {}
    spread = "own_gain_dev" in ens if sur.norm.own is not None else head.map_dev is not None
    if not spread:  # merged before the members' map gains were recorded
        return (
            f"{', '.join(on_map)} follow(s) the static valve map: no member spread there; "
            "the band is the calibrated error quantile by horizon"
        )
    return (
        f"{', '.join(on_map)} follow(s) the static valve map: the members' spread there is "
        "the map's gain spread over the training log, times the distance the map moved it"
    )


@dataclass(frozen=True)
class Calibration:
    """Band half-widths per unit of spread, fitted on validation free runs."""

    levels: tuple[float, ...]
    """Nominal coverages of the bands, e.g. ``(0.5, 0.9)``."""
    theta: np.ndarray
    """(n_level, n_joint) angle band half-width / angle spread."""
    omega: np.ndarray
    """(n_level, n_joint) velocity band half-width / velocity spread."""
    n_step: int
    """Scored (post-warm-up) steps the scales were fitted on."""
    design: str = "shared"
    """How the members ran (``independent`` or ``shared``)."""
    theta_floor: np.ndarray | None = None
    """(n_joint,) smallest angle spread a band uses [rad] (:data:`.bands.FLOOR` x the
    median spread):
    members that agree exactly (e.g. all resting on an end stop) are not certain."""
    omega_floor: np.ndarray | None = None
    """(n_joint,) smallest velocity spread a band uses [rad/s]."""
    rule: str = "val"
    """Which free runs the scales come from (:data:`.bands.RULE`; ``val``: the validation runs
    alone, the rule of calibrations stored before it)."""
    n_run: int = 0
    """Validation runs the scales were fitted on (0: not recorded)."""
    n_train_run: int = 0
    """Training runs the scales were fitted on."""
    horizon_edges: np.ndarray | None = None
    """(n_bin,) int, first step of each horizon bin [samples since the free run began: 0 is
    the first predicted sample] (None: one angle scale at every horizon, ``theta``)."""
    theta_horizon: np.ndarray | None = None
    """(n_level, n_bin, n_joint) angle band half-width / angle spread per horizon bin, not
    decreasing with the horizon (the angle error accumulates faster than the members' angle
    spread grows); the bands use it instead of ``theta`` when present."""

    def theta_scale(self, i: int, horizon: np.ndarray) -> np.ndarray:
        """Angle scale of level ``i`` at ``horizon`` (any shape, samples since the free run
        began; negative: the warm-up, scale of the first bin): ``horizon.shape + (n_joint,)``."""
        h = np.asarray(horizon)
        if self.theta_horizon is None or self.horizon_edges is None:
            return np.broadcast_to(self.theta[i], (*h.shape, self.theta.shape[1]))
        b = np.searchsorted(self.horizon_edges, h, side="right") - 1
        return self.theta_horizon[i][np.clip(b, 0, len(self.horizon_edges) - 1)]

    def floor(self, quantity: str) -> np.ndarray:
        """The spread floor of ``theta`` or ``omega`` (zeros if none was stored)."""
        f = self.theta_floor if quantity == "theta" else self.omega_floor
        return np.zeros(self.theta.shape[1]) if f is None else f

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the checkpoint."""
        return {
            "levels": list(self.levels),
            "theta": self.theta.tolist(),
            "omega": self.omega.tolist(),
            "n_step": int(self.n_step),
            "design": self.design,
            "theta_floor": self.floor("theta").tolist(),
            "omega_floor": self.floor("omega").tolist(),
            "rule": self.rule,
            "n_run": int(self.n_run),
            "n_train_run": int(self.n_train_run),
            **(
                {}
                if self.theta_horizon is None or self.horizon_edges is None
                else {
                    "horizon_edges": [int(v) for v in self.horizon_edges],
                    "theta_horizon": self.theta_horizon.tolist(),
                }
            ),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Calibration:
        """Inverse of :meth:`to_dict` (:class:`CheckpointError` on a malformed record)."""
        try:
            cal = cls(
                levels=tuple(float(v) for v in d["levels"]),
                theta=np.asarray(d["theta"], dtype=np.float64),
                omega=np.asarray(d["omega"], dtype=np.float64),
                n_step=int(d["n_step"]),
                design=str(d.get("design", "shared")),
                theta_floor=np.asarray(d.get("theta_floor", np.zeros(len(d["theta"][0])))),
                omega_floor=np.asarray(d.get("omega_floor", np.zeros(len(d["omega"][0])))),
                rule=str(d.get("rule", "val")),
                n_run=int(d.get("n_run", 0)),
                n_train_run=int(d.get("n_train_run", 0)),
                horizon_edges=None
                if d.get("horizon_edges") is None
                else np.asarray(d["horizon_edges"], dtype=np.int64),
                theta_horizon=None
                if d.get("theta_horizon") is None
                else np.asarray(d["theta_horizon"], dtype=np.float64),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(
                f"malformed uncertainty calibration ({e}); calibrate again"
            ) from e
        bad = cal.theta.shape != cal.omega.shape or cal.theta.shape[0] != len(cal.levels)
        if cal.theta_horizon is not None and cal.horizon_edges is not None:
            n_bin = len(cal.horizon_edges)
            bad |= cal.theta_horizon.shape != (len(cal.levels), n_bin, cal.theta.shape[1])
            bad |= n_bin < 1 or bool(np.any(np.diff(cal.horizon_edges) <= 0))
        if bad:
            raise CheckpointError("malformed uncertainty calibration (sizes); calibrate again")
        return cal


def stored_calibration(sur: Surrogate) -> Calibration | None:
    """The calibration stored in ``sur``'s checkpoint, if any."""
    d = (sur.metrics or {}).get("uncertainty")
    return Calibration.from_dict(d) if isinstance(d, dict) else None


def stored_coverage(sur: Surrogate) -> CoverageRecord | None:
    """The training data's coverage record stored in ``sur``'s checkpoint, if any."""
    d = (sur.metrics or {}).get("coverage")
    return CoverageRecord.from_dict(d) if isinstance(d, dict) else None


@dataclass
class UncertainPrediction:
    """A free run with its spread, bands and flags (arrays ``(n_batch, n_step, n_joint)``;
    steps before ``warmup`` hold the recorded angles, NaN velocities and zero spread)."""

    theta: np.ndarray
    """Central angle [rad]: the merged network's free run."""
    omega: np.ndarray
    """Central velocity [rad/s] (NaN during the warm-up)."""
    warmup: int
    """Recorded samples the run started from."""
    theta_members: np.ndarray | None = None
    """(M, n_batch, n_step, n_joint) each member's angle [rad] (None: single network)."""
    omega_members: np.ndarray | None = None
    """(M, n_batch, n_step, n_joint) each member's velocity [rad/s]."""
    theta_spread: np.ndarray | None = None
    """Std of the members' angles [rad] (None: no members, no uncertainty)."""
    omega_spread: np.ndarray | None = None
    """Std of the members' velocities [rad/s]."""
    bands: dict[float, dict[str, tuple[np.ndarray, np.ndarray]]] | None = None
    """level -> {"theta": (lo, hi), "omega": (lo, hi)} (None: no spread or no calibration)."""
    ood: np.ndarray | None = None
    """(n_batch, n_step, n_joint) bool: outside what training covered (None: no record)."""
    notes: list[str] = field(default_factory=list)
    """One line per missing piece (no members, not calibrated, no coverage record)."""

    @property
    def ood_any(self) -> np.ndarray | None:
        """(n_batch, n_step) bool: any joint flagged."""
        return None if self.ood is None else self.ood.any(-1)


@torch.no_grad()
def member_runs(
    sur: Surrogate,
    theta: np.ndarray,
    u: np.ndarray,
    *,
    warmup: int | None = None,
    design: Design = "shared",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Free-run a merged ensemble and each of its members (see the module docstring).

    Args:
        sur: a merged ensemble with member outputs (:func:`.ensemble.member_head`).
        theta: (n_batch, >= warmup, n_joint) recorded angles [rad].
        u: (n_batch, n_step, n_u) commands.
        warmup: recorded samples to start from (default ``sur.window``).
        design: ``shared`` (members' velocity deviations integrated along the merged run) or
            ``independent`` (each member integrates its own angle).

    Returns:
        ``theta``, ``omega`` (n_batch, n_step, n_joint) of the merged network and
        ``theta_m``, ``omega_m`` (M, n_batch, n_step, n_joint) of the members.
    """
    if design not in ("independent", "shared"):
        raise ConfigError(f"design must be 'independent' or 'shared', got {design!r}")
    warmup = sur.window if warmup is None else int(warmup)
    theta = np.asarray(theta, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    n_batch, n_step, _ = u.shape
    if warmup < 1 or theta.shape[1] < warmup or n_step < warmup:
        raise ValueError(f"need >= warmup={warmup} samples, got theta {theta.shape}, u {u.shape}")
    loop = ClosedLoop(split(sur), members=True)  # stepped as its member blocks
    m = n_member(sur)
    rep = m + 1 if design == "independent" else 1
    th0 = np.concatenate([theta[:, :warmup]] * rep)
    loop.reset(th0, np.concatenate([u[:, : warmup - 1]] * rep))
    if design == "independent":  # rows: the merged run, then member 0's, member 1's, ...
        follow = np.repeat(np.arange(-1, m), n_batch)
        loop.follow = torch.as_tensor(follow, device=sur.device, dtype=torch.long)
    u_t = loop._t(np.concatenate([u] * rep))
    n_row, n_joint = rep * n_batch, sur.spec.n_joint
    th = np.empty((n_row, n_step, n_joint))
    om = np.full_like(th, np.nan)
    th[:, :warmup] = th0
    om_m = np.full((m, n_batch, n_step, n_joint), np.nan)
    for k in range(warmup - 1, n_step - 1):
        t_k, o_k = loop.step(u_t[:, k])
        th[:, k + 1], om[:, k + 1] = t_k.double().cpu().numpy(), o_k.double().cpu().numpy()
        if design == "shared":
            om_m[:, :, k + 1] = loop.omega_members.double().cpu().numpy()
    th_c, om_c = th[:n_batch], om[:n_batch]
    if design == "independent":
        th_m = th[n_batch:].reshape(m, n_batch, n_step, n_joint)
        om_m = om[n_batch:].reshape(m, n_batch, n_step, n_joint)
    else:  # each member's velocity along the shared run, its deviation integrated
        th_m = shared_member_angles(th_c, om_c, om_m, dt=sur.spec.dt, limits=sur.limits_np())
    return th_c, om_c, th_m, om_m


def shared_member_angles(
    theta: np.ndarray,
    omega: np.ndarray,
    omega_m: np.ndarray,
    *,
    dt: float,
    limits: tuple[np.ndarray, ...] | None,
) -> np.ndarray:
    """The members' angles of the ``shared`` design: each member's velocity deviation from
    the merged run, integrated along it and stopped where the merged run's end stops are::

        theta_m[k+1] = clip(theta_m[k] + (theta[k+1] - theta[k]) + T_s (omega_m[k+1] - omega[k+1]), lo, hi)

    (the recorded angle during the warm-up; the stops widened to ``theta[k+1]`` where the merged
    run is beyond one).

    Args:
        theta, omega: (n_batch, n_step, n_joint) the merged run [rad], [rad/s] (``omega`` NaN
            during the warm-up).
        omega_m: (M, n_batch, n_step, n_joint) the members' velocities along it [rad/s].
        dt: sample period T_s [s].
        limits: ``(lo, hi[, omega_max])`` of :meth:`.model.Surrogate.limits_np`, or None.

    Returns:
        ``theta_m``: (M, n_batch, n_step, n_joint) [rad].  Without the stops a member pushing
        into a stop the merged run rests on kept integrating, hundreds of degrees past it.
    """
    dev = np.nan_to_num(omega_m - omega[None]) * dt  # (M, n_batch, n_step, n_joint)
    if limits is None:
        return theta[None] + np.cumsum(dev, axis=2)
    th_m = np.empty_like(dev)
    th_m[:, :, 0] = theta[None, :, 0]
    for k in range(dev.shape[2] - 1):
        nxt = th_m[:, :, k] + (theta[:, k + 1] - theta[:, k]) + dev[:, :, k + 1]
        # the stops, widened to the merged run's own angle (a start beyond a stop stays there)
        lo = np.minimum(limits[0], theta[:, k + 1])
        hi = np.maximum(limits[1], theta[:, k + 1])
        recorded = np.isnan(omega[:, k + 1])  # the warm-up: the recorded angle
        th_m[:, :, k + 1] = np.where(recorded, theta[:, k + 1], np.clip(nxt, lo, hi))
    return th_m


def _std(a: np.ndarray) -> np.ndarray:
    """Std over the member axis 0 (ddof 1), NaN kept where the members are NaN."""
    return np.std(a, axis=0, ddof=1)


def predict_with_uncertainty(
    sur: Surrogate,
    theta: np.ndarray,
    u: np.ndarray,
    *,
    warmup: int | None = None,
    design: Design | None = None,
    calibration: Calibration | None = None,
    coverage: CoverageRecord | None = None,
    read_calibration: bool = True,
) -> UncertainPrediction:
    """Free-run ``u`` with the central prediction, member spread, bands and OOD flags.

    Args:
        sur: the surrogate (a merged seed ensemble for spread and bands).
        theta: (n_batch, >= warmup, n_joint) recorded angles to start from [rad].
        u: (n_batch, n_step, n_u) commands [command units] (joints', then exogenous inputs').
        warmup: recorded samples to start from (default ``sur.window``).
        design: how the members run (default: the calibration's, else ``shared``).
        calibration: band scales (default: the checkpoint's, :func:`stored_calibration`).
        coverage: training coverage (default: the checkpoint's, :func:`stored_coverage`).
        read_calibration: False: the checkpoint's calibration is not read (no bands unless
            ``calibration`` is given): a new calibration's free runs, which a malformed old
            record must not stop.

    Returns:
        :class:`UncertainPrediction`; a single network gives ``theta_spread is None`` and a note.
    """
    warmup = sur.window if warmup is None else int(warmup)
    if calibration is None and read_calibration:
        calibration = stored_calibration(sur)
    coverage = coverage if coverage is not None else stored_coverage(sur)
    design = design or (calibration.design if calibration is not None else "shared")  # type: ignore[assignment]
    notes: list[str] = []
    if member_head(sur) is not None:
        th, om, th_m, om_m = member_runs(sur, theta, u, warmup=warmup, design=design)
        pred = UncertainPrediction(th, om, warmup, th_m, om_m, _std(th_m), _std(om_m))
        if calibration is None:
            notes.append("ensemble not calibrated: spread only, no bands (run 'exsur calibrate')")
        else:
            pred.bands = bands(pred, calibration)
        if (note := map_note(sur)) is not None:
            notes.append(note)
    else:
        th, om = rollout(sur, theta, u, warmup=warmup)
        pred = UncertainPrediction(th, om, warmup)
        notes.append(
            NO_MEMBERS
            if n_member(sur) < 2
            else "ensemble merged by an older exsur: no member outputs (merge it again)"
        )
    if coverage is None:
        notes.append("no training coverage record: no out-of-distribution flags")
    else:
        pred.ood = ood_flags(coverage, sur.spec, pred.theta, pred.omega, np.asarray(u))
    pred.notes = notes
    return pred


def bands(
    pred: UncertainPrediction, cal: Calibration
) -> dict[float, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """``level -> {"theta": (lo, hi), "omega": (lo, hi)}``: central +/- scale x spread (the
    angle scale per horizon bin when the calibration has them, :meth:`Calibration.theta_scale`)."""
    assert pred.theta_spread is not None and pred.omega_spread is not None
    out: dict[float, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    horizon = np.arange(pred.theta.shape[-2]) - pred.warmup  # (n_step,)
    for i, level in enumerate(cal.levels):
        d = {}
        for q, c, s, k in (
            ("theta", pred.theta, pred.theta_spread, cal.theta_scale(i, horizon)),
            ("omega", pred.omega, pred.omega_spread, cal.omega[i]),
        ):
            half = k * np.maximum(s, cal.floor(q))
            d[q] = (c - half, c + half)
        out[level] = d
    return out
