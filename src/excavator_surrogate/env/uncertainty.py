"""Per-step uncertainty and out-of-distribution flags inside :class:`~.engine.SurrogateEngine`.

The batched counterpart of :func:`~excavator_surrogate.surrogate.uncertainty.predict_with_uncertainty`
(design ``shared``), for the environments:

- the members' velocities come from the SAME network call as the central one: the engine's
  head activations ``a = relu(W1 out + b1)`` (stateful) or a hook on the network's head
  (windowed) go through each member's block of the output layer
  (:class:`~excavator_surrogate.surrogate.ensemble.MemberHead`), nothing runs twice;
- member ``m``'s angle is the central angle plus its integrated velocity deviation
  ``dev_m += T_s (omega_m - omega)``, a per-env state zeroed by (masked) resets;
- the band is the calibrated 90 % half-width ``k_90 max(std, floor)`` per joint when the
  checkpoint is calibrated (``metrics["uncertainty"]``; the angle's ``k_90`` of the horizon
  bin of the steps since the env's reset, when the calibration has bins), else the raw std
  over the members;
- the OOD flag of a step checks the sample the network predicted from (``theta[k]``,
  ``omega[k]``, ``u[k]``) against the training coverage record (``metrics["coverage"]``),
  as :func:`~excavator_surrogate.surrogate.coverage.ood_flags` does, in torch.

A single network has no members: its bands are None and ``has_spread`` is False (never zeros).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..spec import MachineSpec
from ..surrogate.angles import Limits
from ..surrogate.coverage import CoverageRecord, channel_names, seen_cells, turn_centres
from ..surrogate.ensemble import MemberHead, member_head
from ..surrogate.model import Surrogate
from ..surrogate.uncertainty import NO_MEMBERS, map_note, stored_calibration, stored_coverage

LEVEL = 0.9
"""Nominal coverage of the band the environments report."""


INFO_KEYS = (
    "uncertainty",
    "band_calibrated",
    "theta_band",
    "omega_band",
    "ood",
    "ood_any",
    "ood_checked",
)
"""The step ``info`` keys of the surrogate environments (see :func:`step_info`)."""


def wanted(sur: Surrogate, uncertainty: bool | None) -> bool:
    """Whether an env tracks uncertainty: ``uncertainty`` if given, else when ``sur`` has
    something to report (ensemble members or a training coverage record)."""
    if uncertainty is not None:
        return bool(uncertainty)
    return member_head(sur) is not None or stored_coverage(sur) is not None


def step_info(unc: StepUncertainty | None, n_envs: int, n_joint: int) -> dict[str, np.ndarray]:
    """The uncertainty entries of a step's ``info`` for ``n_envs`` rows (NumPy copies, each
    with first axis ``n_envs``, as gymnasium's vector ``info`` wants them):

    - ``uncertainty`` (n_envs,) bool: the bands are the ensemble members' spread (False: a
      single network or tracking off; the bands are then None, never zeros);
    - ``band_calibrated`` (n_envs,) bool: the bands are the calibrated 90 % half-widths (False:
      the raw member std);
    - ``theta_band`` (n_envs, n_joint) [rad], ``omega_band`` (n_envs, n_joint) [rad/s], or
      without members (n_envs,) object arrays of None (what ``SyncVectorEnv`` batches from
      the single env's None);
    - ``ood`` (n_envs, n_joint) bool: the step's sample (theta, omega, u) left what training
      covered; ``ood_any`` (n_envs,) bool: any joint;
    - ``ood_checked`` (n_envs,) bool: a coverage record was checked (False: ``ood`` is all
      False because nothing could be checked).
    """
    none = lambda: np.full(n_envs, None, dtype=object)  # noqa: E731
    if unc is None:
        no = np.zeros(n_envs, dtype=bool)
        flags = np.zeros((n_envs, n_joint), dtype=bool)
        return dict(zip(INFO_KEYS, (no, no.copy(), none(), none(), flags, no.copy(), no.copy())))
    th, om = unc.bands() if unc.n_member else (None, None)
    ood = unc.ood.cpu().numpy().copy()
    return {
        "uncertainty": np.full(n_envs, unc.has_spread),
        "band_calibrated": np.full(n_envs, unc.calibrated),
        "theta_band": none() if th is None else th.cpu().numpy(),
        "omega_band": none() if om is None else om.cpu().numpy(),
        "ood": ood,
        "ood_any": ood.any(-1),
        "ood_checked": np.full(n_envs, unc.checked),
    }


def notes(sur: Surrogate) -> list[str]:
    """One line per missing piece of ``sur``'s uncertainty (empty: bands and flags)."""
    out = []
    if member_head(sur) is None:
        out.append(NO_MEMBERS)
    elif stored_calibration(sur) is None:
        out.append("ensemble not calibrated: bands are the raw member std (run 'exsur calibrate')")
    if stored_coverage(sur) is None:
        out.append("no training coverage record: no out-of-distribution flags")
    if (note := map_note(sur)) is not None:
        out.append(note)
    return out


class OodFlags(torch.nn.Module):
    """:func:`~excavator_surrogate.surrogate.coverage.ood_flags` of one step in torch tensor
    ops (box test on command, angle and velocity, the (angle, command) occupancy grid with its
    one-cell tolerance): the engine's flags and the ONNX ``ood`` output.

    ``forward(theta, u, omega)``: ``theta`` (n, n_joint) [rad], ``u`` (n, n_u), ``omega``
    (n, n_joint) [rad/s] of one sample (NaN values are not checked) -> (n, n_joint) bool.

    Args:
        rec: the training data's coverage record (channels in ``spec``'s order).
        spec: the machine.
        dtype: of the record's bounds (the inputs are compared in it).
    """

    def __init__(self, rec: CoverageRecord, spec: MachineSpec, *, dtype: torch.dtype) -> None:
        super().__init__()
        n_joint, n_u = spec.n_joint, spec.n_u
        self.n_joint, self.n_u, self.n_bin = n_joint, n_u, rec.n_bin
        t = lambda a: torch.as_tensor(np.asarray(a), dtype=dtype)  # noqa: E731
        iu, it = np.arange(n_joint), n_u + np.arange(n_joint)
        self.register_buffer("lo", t(rec.lo))
        self.register_buffer("hi", t(rec.hi))
        self.register_buffer("t_lo", t(rec.lo[it]))
        self.register_buffer("t_hi", t(rec.hi[it]))
        self.register_buffer("t_span", t(np.maximum(rec.hi[it] - rec.lo[it], 1e-12)))
        self.register_buffer("u_lo", t(rec.lo[iu]))
        self.register_buffer("u_hi", t(rec.hi[iu]))
        self.register_buffer("u_span", t(np.maximum(rec.hi[iu] - rec.lo[iu], 1e-12)))
        self.register_buffer("seen", torch.as_tensor(seen_cells(rec.grid).reshape(-1)))
        cell0 = np.arange(n_joint) * rec.n_bin * rec.n_bin
        self.register_buffer("cell0", torch.as_tensor(cell0, dtype=torch.long))
        # a periodic joint's angle is checked on the record's turn (coverage.on_box_turn):
        # every angle round the fit centre, or (older record) one outside its box round its middle
        per = np.asarray(spec.periodic, dtype=bool)
        self.periodic = bool(per.any())
        centre, self.every_turned = turn_centres(rec, spec)
        self.register_buffer("per", torch.as_tensor(per))
        self.register_buffer("t_mid", t(centre))

    def forward(self, theta: torch.Tensor, u: torch.Tensor, omega: torch.Tensor) -> torch.Tensor:
        """See the class docstring."""
        n_joint, n_u, nb = self.n_joint, self.n_u, self.n_bin
        if self.periodic:
            # theta_j <- c_j + wrap(theta_j - c_j) on the periodic joints (an older record:
            # those outside their box, round its middle)
            th = theta.to(self.lo.dtype)
            d = th - self.t_mid
            turned = self.t_mid + d - 2 * math.pi * torch.floor((d + math.pi) / (2 * math.pi))
            move = self.per
            if not self.every_turned:
                move = move & ((th < self.t_lo) | (th > self.t_hi))
            theta = torch.where(move, turned, th)
        x = torch.cat([u, theta, omega], dim=-1).to(self.lo.dtype)
        out = torch.isfinite(x) & ((x < self.lo) | (x > self.hi))
        flag = out[:, :n_joint] | out[:, n_u : n_u + n_joint] | out[:, n_u + n_joint :]
        if n_u > n_joint:  # an exogenous input outside its box flags every joint
            flag = flag | out[:, n_joint:n_u].any(-1, keepdim=True)
        th, uu = x[:, n_u : n_u + n_joint], x[:, :n_joint]
        inside = (th >= self.t_lo) & (th <= self.t_hi) & (uu >= self.u_lo) & (uu <= self.u_hi)
        bt = torch.floor((th - self.t_lo) / self.t_span * nb)
        bu = torch.floor((uu - self.u_lo) / self.u_span * nb)
        bt = torch.nan_to_num(bt).clamp(0, nb - 1).long()
        bu = torch.nan_to_num(bu).clamp(0, nb - 1).long()
        seen = self.seen[self.cell0 + bt * nb + bu]
        return flag | (inside & ~seen)


def member_std(x: torch.Tensor) -> torch.Tensor:
    """Standard deviation over the members (ddof 1) of ``x: (M, ...)``, M >= 2: ``torch.std(x,
    dim=0)`` up to rounding, as a loop over the few members (``torch.std`` over a short
    leading dimension took 0.6 ms for (2, 1024, 4) float64 on a 1-thread AVX-512 CPU, the
    loop 0.04 ms: a third of the vector env's step at 1024 envs)::

        mean = sum_m x_m / M,    std = sqrt( sum_m (x_m - mean)^2 / (M - 1) )
    """
    m = x.shape[0]
    mean = x.sum(dim=0).div_(m)
    ss = (x[0] - mean).square_()
    for i in range(1, m):
        ss.add_((x[i] - mean).square_())
    return ss.div_(m - 1).sqrt_()


class StepUncertainty:
    """Member deviations, bands and OOD flags of ``n_envs`` engine rows.

    Args:
        sur: the engine's surrogate (on the engine's device, float32).
        n_envs: batch size.
        additive: the head's output is added to a base (the velocity feature of a residual
            head, or a speed prior's speed), so it carries no ``y_mean``.

    State: ``dev`` (M, n_envs, n_joint) float64 [rad], ``omega`` (n_envs, n_joint) float64
    [rad/s] (the velocity of the current sample, 0 at rest), ``omega_members`` (M, n_envs,
    n_joint) [rad/s] and ``ood`` (n_envs, n_joint) bool of the last step.
    """

    def __init__(
        self,
        sur: Surrogate,
        *,
        n_envs: int,
        additive: bool = False,
    ) -> None:
        dev = sur.device
        n_joint = sur.spec.n_joint
        self.spec = sur.spec
        self.dt = float(sur.spec.dt)
        self.head: MemberHead | None = member_head(sur)
        self.has_spread = self.head is not None
        self.n_member = self.head.n_member if self.head is not None else 0
        self.additive = additive
        self.omega = torch.zeros(n_envs, n_joint, dtype=torch.float64, device=dev)
        self.dev = torch.zeros(self.n_member, n_envs, n_joint, dtype=torch.float64, device=dev)
        self.omega_members = torch.full_like(self.dev, float("nan"))
        self.ood = torch.zeros(n_envs, n_joint, dtype=torch.bool, device=dev)
        self.map_dev: torch.Tensor | None = None
        if self.head is not None:
            # member m: omega_m = M W2[:, block_m] a_m + y_std beta_m (+ y_mean | + base)
            # a static-map joint: member m's base is (1 + map_dev[m]) s(u)
            self.w2m, self.b2m, self.map_dev = self.head.folded(sur.norm, additive=additive)
        cal = stored_calibration(sur)
        self.calibrated = cal is not None and self.has_spread
        if cal is not None:
            i = int(np.argmin(np.abs(np.asarray(cal.levels) - LEVEL)))
            self.level = float(cal.levels[i])
            t = lambda a: torch.as_tensor(a, dtype=torch.float64, device=dev)  # noqa: E731
            self.k = (t(cal.theta[i]), t(cal.omega[i]))
            self.floor = (t(cal.floor("theta")), t(cal.floor("omega")))
            # the angle scale per horizon bin (n_bin, n_joint) and the bins' first steps
            self.k_horizon = None if cal.theta_horizon is None else t(cal.theta_horizon[i])
            self.edges = (
                None
                if cal.horizon_edges is None
                else torch.as_tensor(cal.horizon_edges, dtype=torch.long, device=dev)
            )
        self.steps = torch.zeros(n_envs, dtype=torch.long, device=dev)
        """(n_envs,) steps since each env's reset."""
        rec = stored_coverage(sur)
        self.checked = rec is not None and rec.channels == channel_names(sur.spec)
        self.box: OodFlags | None = None
        if rec is not None and self.checked:
            self.box = OodFlags(rec, sur.spec, dtype=torch.float64).to(dev)
        self.notes = notes(sur)

    def reset(self, idx: torch.Tensor) -> None:
        """Rows ``idx`` start at rest: no deviation, zero velocity, no flag."""
        self.omega.index_fill_(0, idx, 0.0)
        self.ood.index_fill_(0, idx, False)
        self.steps.index_fill_(0, idx, 0)
        if self.n_member:
            self.dev.index_fill_(1, idx, 0.0)
            self.omega_members.index_fill_(1, idx, float("nan"))

    def flag(self, theta: torch.Tensor, u: torch.Tensor) -> None:
        """OOD flags of the sample ``theta[k]`` (n_envs, n_joint), ``omega[k]`` (the state),
        ``u[k]`` (n_envs, n_u) before the step (see :func:`~...coverage.ood_flags`)."""
        if self.box is not None:
            self.ood.copy_(self.box(theta, u.double(), self.omega))

    def members_from_activations(self, a: torch.Tensor, base: torch.Tensor | None) -> torch.Tensor:
        """Each member's omega (M, n_envs, n_joint) float32 [rad/s] from the engine's head
        activations ``a`` (n_envs, f_tot) and the ``base`` the head adds to (n_envs, n_joint)
        [rad/s] (velocity feature or speed prior; None: none)."""
        om = torch.baddbmm(self.b2m, a.unsqueeze(0).expand(self.n_member, -1, -1), self.w2m)
        if not self.additive or base is None:
            return om
        if self.map_dev is not None:  # the base is the speed prior's s(u)
            return om + base + self.map_dev * base
        return om + base

    def advance(
        self,
        omega_members: torch.Tensor | None,
        omega: torch.Tensor,
        *,
        theta: torch.Tensor | None = None,
        limits: Limits | None = None,
    ) -> None:
        """After a step: members' ``omega_members`` (M, n_envs, n_joint) [rad/s] (None
        without members) and the integrated central ``omega[k+1]`` (n_envs, n_joint) float64;
        with ``theta[k+1]`` (n_envs, n_joint) float64 and the engine's ``limits``, each member's
        angle ``theta + dev_m`` stays inside the end stops, as
        :func:`~excavator_surrogate.surrogate.uncertainty.shared_member_angles` keeps it::

            dev_m <- clip(theta + dev_m + T_s (omega_m - omega), lo, hi) - theta
        """
        if omega_members is not None:
            om_m = omega_members.double()
            self.omega_members = om_m
            self.dev.add_(torch.nan_to_num(om_m - omega), alpha=self.dt)
            if theta is not None and limits is not None:
                # the stops, widened to the central angle where it is beyond one
                lo, hi = torch.minimum(limits[0], theta), torch.maximum(limits[1], theta)
                self.dev.copy_(torch.clamp(theta + self.dev, lo, hi) - theta)
        self.omega.copy_(omega)
        self.steps.add_(1)

    def bands(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``theta_band``, ``omega_band`` (n_envs, n_joint) float64 [rad], [rad/s]: the
        calibrated half-width at :attr:`level` or the raw member std; NaN without members."""
        if not self.n_member:
            nan = torch.full_like(self.omega, float("nan"))
            return nan, nan.clone()
        s_t = member_std(self.dev)  # = std of theta_m = theta + dev_m (ddof 1)
        s_w = member_std(self.omega_members)
        if not self.calibrated:
            return s_t, s_w
        k_t = self.k[0]
        if self.k_horizon is not None and self.edges is not None:
            # the last step predicted sample k = steps - 1 of the free run (0: the first)
            b = torch.bucketize(self.steps - 1, self.edges, right=True) - 1
            k_t = self.k_horizon[b.clamp_(0, len(self.edges) - 1)]
        return (
            k_t * torch.maximum(s_t, self.floor[0]),
            self.k[1] * torch.maximum(s_w, self.floor[1]),
        )
