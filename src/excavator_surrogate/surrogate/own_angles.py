"""Static-map joints composed in parallel: the network keeps reading its own angles.

A joint put on the static valve map after training (``training/map_joints.py``) can be
composed with the network in two ways:

- **in series** (:func:`.series.with_map_joints`): the map drives the joint's angle and
  the network reads that angle, as it reads every joint's;
- **in parallel** (:func:`.parallel.with_parallel_map`, this module): the map drives the
  joint's reported angle, while the network reads its *own* angle of that joint, integrated
  from its own (dropped) velocity, exactly as in its free run alone.

A network's joints are coupled through what they read: on the continuous dev case the arm's
network, reading a map-driven bucket it never saw in its own free run, drifted 1.6x further
on the test (docs/real-history.md, session 29).  In parallel, the network's free run is the
network's own and a map joint's angle depends on its own command only, so every joint scores
as its source scores alone, and the choice can be made per joint.

The network's own angle ``theta_own`` and velocity ``omega_own`` of every joint ride in two
rows after the command state ``z`` (:attr:`.features.Normalization.n_own`), so every runtime
that carries ``z`` (free run, environments, forks, ONNX) carries them.  One step::

    theta_in  = where(own, theta_own[k], theta[k])       what the network reads
    omega_in  = where(own, omega_own[k], omega[k])       (its velocity feature, if any)
    omega_net = network(theta_in, u[k], z, omega_in)     its own omega[k+1], every joint
    theta_own[k+1], omega_own[k+1] = integrate(theta_own[k], omega_net)   (the network's end stops)
    omega[k+1] = where(own, s(u[k - d]), omega_net)      the reported speed
    theta[k+1] = integrate(theta[k], omega[k+1])         (the model's end stops)

The model's end stops are the spec's; a map joint's may be tighter than the network's (the
structured model's: the training range), and then :class:`OwnMap` keeps the network's for the
own rows, so the network's free run stays its own.

with the map ``s_j(u) = k_pos,j max(u_j - a_pos,j, 0) - k_neg,j max(a_neg,j - u_j, 0)`` of the
joint's command ``d_j`` samples back (from the command delay line; ``d_j = 0``: the current
command).  :class:`OwnMap` holds the map and the joints (:attr:`.features.Normalization.own`);
:func:`network_inputs` and :func:`own_advance` are the step's two halves and :func:`own_start`
sets the network's own angle at a reset or a measured sample.  Every function returns its
input unchanged when the normalisation has no such joints.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import torch

from .angles import integrate

OWN_FIELDS = ("a_pos", "a_neg", "k_pos", "k_neg")
"""The map's per-joint tensors, ``(n_joint,)`` each (raw command units; rad/s per command unit)."""
OWN_STOPS = ("theta_min", "theta_max")
"""The network's own end stops, ``(n_joint,)`` each [rad], when the map joints stop elsewhere."""
N_OWN_ROWS = 2
"""Rows of ``z`` after the command state: the network's own angle [rad], then its own velocity
[rad/s], per joint."""


@dataclass
class OwnMap:
    """The joints that follow a static map in parallel with the network, and the map.

    ``own``: (n_joint,) which joints report the map's speed; ``a_pos``, ``a_neg`` [command
    units] the dead zone, ``k_pos``, ``k_neg`` [rad/s per command unit] the gains (0 off
    ``own``); ``delay``: (n_joint,) the samples ``d_j`` each joint's map reads its command back;
    ``theta_min``, ``theta_max``: (n_joint,) the network's own end stops [rad] (+-inf: none),
    where the map joints' reported angles stop elsewhere (None: the model's end stops).
    """

    own: tuple[bool, ...]
    a_pos: torch.Tensor
    a_neg: torch.Tensor
    k_pos: torch.Tensor
    k_neg: torch.Tensor
    delay: tuple[int, ...]
    theta_min: torch.Tensor | None = None
    theta_max: torch.Tensor | None = None

    def __post_init__(self) -> None:
        n = len(self.own)
        if not any(self.own):
            raise ValueError("an own-angle map needs at least one joint on it")
        if len(self.delay) != n or min(self.delay) < 0:
            raise ValueError(f"delay must be one value >= 0 per joint, got {list(self.delay)}")
        for k in OWN_FIELDS:
            if tuple(getattr(self, k).shape) != (n,):
                raise ValueError(f"own map {k} must have shape ({n},)")
        if (self.theta_min is None) != (self.theta_max is None):
            raise ValueError("own map: give both theta_min and theta_max, or neither")
        for k in OWN_STOPS:
            t = getattr(self, k)
            if t is not None and tuple(t.shape) != (n,):
                raise ValueError(f"own map {k} must have shape ({n},)")
        self.own_mask = torch.tensor(self.own, device=self.a_pos.device)
        """(n_joint,) bool :attr:`own` on the map's device."""

    @classmethod
    def from_fit(
        cls, fit: Any, own: Sequence[bool], *, delay: Sequence[int] | None = None
    ) -> OwnMap:
        """From a :func:`.structured.fit_prior` map (``a_pos`` ... per joint, optional
        ``delay``), with the gains of the joints off ``own`` set to 0."""
        pick = tuple(bool(p) for p in own)
        n = len(pick)
        d = delay if delay is not None else fit.get("delay", [0] * n)

        def t(name: str) -> torch.Tensor:
            return torch.tensor([float(v) if p else 0.0 for v, p in zip(fit[name], pick)])

        return cls(
            own=pick,
            **{k: t(k) for k in OWN_FIELDS},
            delay=tuple(int(v) if p else 0 for v, p in zip(d, pick)),
        )

    def to(self, device: torch.device | str, dtype: torch.dtype = torch.float32) -> OwnMap:
        """Copy with the tensors on ``device`` / ``dtype``."""
        kw = {k: getattr(self, k).to(device=device, dtype=dtype) for k in OWN_FIELDS}
        for k in OWN_STOPS:
            t = getattr(self, k)
            kw[k] = None if t is None else t.to(device=device, dtype=dtype)
        return OwnMap(own=self.own, delay=self.delay, **kw)

    def with_stops(self, lo: Sequence[float], hi: Sequence[float]) -> OwnMap:
        """A copy whose own rows stop at ``lo`` / ``hi`` (n_joint,) [rad] (float64)."""
        t = {"dtype": torch.float64}
        return replace(self, theta_min=torch.tensor(lo, **t), theta_max=torch.tensor(hi, **t))

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Plain tensors for the checkpoint's ``norm`` entry (keys ``own_*``; the end stops in
        float64, as the spec holds them)."""
        out = {f"own_{k}": getattr(self, k).detach().cpu().float() for k in OWN_FIELDS}
        out["own_joints"] = torch.tensor(self.own, dtype=torch.float32)
        out["own_delay"] = torch.tensor(self.delay, dtype=torch.float32)
        for k in OWN_STOPS:
            t = getattr(self, k)
            if t is not None:
                out[f"own_{k}"] = t.detach().cpu().double()
        return out

    @classmethod
    def from_state_dict(cls, d: dict[str, Any]) -> OwnMap | None:
        """Inverse of :meth:`state_dict`; None when ``d`` has no ``own_joints`` entry."""
        if "own_joints" not in d:
            return None
        own = tuple(bool(float(v)) for v in torch.as_tensor(d["own_joints"]).reshape(-1))
        delay = tuple(round(float(v)) for v in torch.as_tensor(d["own_delay"]).reshape(-1))
        kw: dict[str, Any] = {
            k: torch.as_tensor(d[f"own_{k}"]).float().reshape(-1).clone() for k in OWN_FIELDS
        }
        for k in OWN_STOPS:  # a checkpoint from before these were kept: the model's stops
            if f"own_{k}" in d:
                kw[k] = torch.as_tensor(d[f"own_{k}"]).double().reshape(-1).clone()
        return cls(own=own, delay=delay, **kw)

    def speed(self, u: torch.Tensor) -> torch.Tensor:
        """The map's speed ``s(u)`` (..., n_joint) [rad/s] of raw joint commands ``u``
        (..., n_joint) [command units] (0 off :attr:`own`)::

            s_j(u) = k_pos,j max(u_j - a_pos,j, 0) - k_neg,j max(a_neg,j - u_j, 0)
        """
        return self.k_pos * torch.relu(u - self.a_pos) - self.k_neg * torch.relu(self.a_neg - u)


class OwnRows(Protocol):
    """What these functions read of a :class:`.features.Normalization` (which imports this
    module, so it is not imported here)."""

    own: OwnMap | None
    periodic: tuple[bool, ...]
    u_center: torch.Tensor
    u_scale: torch.Tensor

    @property
    def n_play(self) -> int: ...
    @property
    def n_line(self) -> int: ...
    @property
    def n_command(self) -> int: ...


def network_inputs(
    norm: OwnRows,
    theta: torch.Tensor,
    z: torch.Tensor | None,
    omega: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The angles ``(..., n_joint)`` [rad] and velocity feature [rad/s] the network reads:
    ``theta`` and ``omega``, except on the ``norm.own`` joints, where they are the network's
    own from ``z`` (..., n_state, n_joint) (``omega`` None stays None)."""
    if norm.own is None:
        return theta, omega
    if z is None:
        raise ValueError("joints on a static map in parallel: pass z")
    c, pick = norm.n_command, norm.own.own_mask
    # theta_in = where(own, theta_own, theta);  omega_in = where(own, omega_own, omega)
    th = torch.where(pick, z[..., c, :].to(theta.dtype), theta)
    if omega is None:
        return th, None
    return th, torch.where(pick, z[..., c + 1, :].to(omega.dtype), omega)


def own_start(
    norm: OwnRows,
    z: torch.Tensor,
    theta: torch.Tensor,
    omega: torch.Tensor | None = None,
) -> torch.Tensor:
    """``z`` (..., n_state, n_joint) with the network's own angle set to ``theta`` (...,
    n_joint) [rad] and its own velocity to ``omega`` [rad/s] (None: 0): a reset, or a measured
    sample that the network reads (a new tensor)."""
    if norm.own is None:
        return z
    c = norm.n_command
    w = torch.zeros_like(theta) if omega is None else omega
    rows = torch.stack([theta.to(z.dtype), w.to(z.dtype)], dim=-2)
    return torch.cat([z[..., :c, :], rows.expand(*z.shape[:-2], N_OWN_ROWS, z.shape[-1])], dim=-2)


def own_advance(
    norm: OwnRows,
    z: torch.Tensor,
    u: torch.Tensor,
    omega_net: torch.Tensor,
    *,
    dt: float,
    limits: Sequence[torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """After the network's step: the speed to integrate and the new ``z``.

    Args:
        norm: the normalisation (``norm.own`` the map).
        z: (..., n_state, n_joint) after :meth:`~.features.Normalization.play_update` of ``u``.
        u: (..., n_u) the commands u[k] [command units].
        omega_net: (..., n_joint) the network's omega[k+1] [rad/s] on every joint.
        dt: sample period [s].
        limits: the end stops and speed bounds (:func:`.angles.integrate`), or None.

    Returns:
        ``omega``: (..., n_joint) omega[k+1], the map's ``s(u[k - d])`` on the own joints
        and ``omega_net`` elsewhere; and ``z`` with the network's own angle and velocity moved
        by ``omega_net``.
    """
    if norm.own is None:
        return omega_net, z
    own, c, nj = norm.own, norm.n_command, len(norm.periodic)
    lim = None if limits is None else tuple(a.to(z) for a in limits)
    if lim is not None and own.theta_min is not None and own.theta_max is not None:
        # the network's own angles keep the network's end stops (the map joints' are the map's)
        lim = (own.theta_min.to(z), own.theta_max.to(z), *lim[2:])
    # theta_own[k+1], omega_own[k+1] = integrate(theta_own[k], omega_net[k+1])
    th, w = integrate(z[..., c, :], omega_net.to(z.dtype), dt=dt, limits=lim)
    if norm.n_line:  # each joint's scaled command d_j back: delay line row L - 1 - d_j
        rows = torch.tensor([norm.n_line - 1 - d for d in own.delay], device=z.device)
        us = z[..., norm.n_play + rows, torch.arange(nj, device=z.device)]
        u_d = us * norm.u_scale[:nj] + norm.u_center[:nj]
    else:  # every map delay is 0: the current command
        u_d = u[..., :nj]
    # omega[k+1] = where(own, s(u[k - d]), omega_net[k+1])
    s = own.speed(u_d.to(own.a_pos.dtype)).to(omega_net.dtype)
    omega = torch.where(own.own_mask, s, omega_net)
    z = torch.cat([z[..., :c, :], th.unsqueeze(-2), w.unsqueeze(-2)], dim=-2)
    return omega, z


def own_members(
    norm: OwnRows, omega_members: torch.Tensor, omega: torch.Tensor, dev: torch.Tensor
) -> torch.Tensor:
    """The ensemble members' speeds with the joints on the map in parallel driven by the map:
    member ``m`` drives such a joint with gain ``1 + dev[m]``.

    Args:
        norm: the normalisation (``norm.own`` the map; None: ``omega_members`` unchanged).
        omega_members: (M, ..., n_joint) each member's speed [rad/s] from the network.
        omega: (..., n_joint) the speed :func:`own_advance` returned (the map's on its joints).
        dev: (M, n_joint) the members' gain deviations
            (:func:`~excavator_surrogate.surrogate.parallel.own_gain_dev`).
    """
    if norm.own is None:
        return omega_members
    d = dev.to(omega_members).reshape(dev.shape[0], *[1] * (omega_members.dim() - 2), -1)
    # omega_m = where(own, (1 + dev[m]) omega, omega_m)
    gain = omega.to(omega_members).unsqueeze(0) * (1.0 + d)
    return torch.where(norm.own.own_mask, gain, omega_members)
