"""The torch modules an ONNX export traces: the windowed step and the wrappers that order a
stateful or windowed step's inputs and outputs as the graph names them.

:mod:`.export` documents the graph's inputs, outputs and metadata, and traces these: the
stateful graph is :class:`~.fused.FusedStep` (or :class:`~.fused.FusedMembersStep` with the
member outputs), wrapped in :class:`StatefulOod` for the ``ood`` output and in
:class:`StatefulVelocityOnly` when the velocity feature ``w`` follows ``h``, ``c`` without a
``z``; the windowed graph is :class:`WindowStep`, wrapped in :class:`WindowVelocityOnly` in
that case.
"""

from __future__ import annotations

import torch
from torch import nn

from ..surrogate.angles import integrate
from ..surrogate.command_state import command_features
from ..surrogate.model import Surrogate
from ..surrogate.own_angles import network_inputs, own_advance
from .fused import FusedMembersStep, add_end_stops, end_stops
from .uncertainty import OodFlags


class WindowStep(nn.Module):
    """Windowed step with encoding and normalisation in the graph:
    ``(theta (n, W, J), u (n, W, n_u)[, z (n, W, S, J)][, w (n, W, J)]) -> (omega (n, J),
    theta_next (n, J)[, z_out (n, S, J)])`` (``u``: the joints' commands, then the exogenous
    inputs'; ``z``: the command states after each sample's ``u``, ``S = Q + L [+ 2]`` rows;
    ``w``: the velocity features [rad/s]).

    With joints on a static map in parallel (``norm.own``) the network reads, at every
    sample, its own angle and velocity of them from that sample's ``z``
    (:func:`~excavator_surrogate.surrogate.own_angles.network_inputs`), ``omega`` there is the
    map's speed, and ``z_out`` is the last sample's ``z`` with the own rows moved by the
    network's speed (:func:`~excavator_surrogate.surrogate.own_angles.own_advance`): the
    caller's ``z`` for the next step, before its command."""

    def __init__(self, sur: Surrogate) -> None:
        super().__init__()
        self.net = sur.net
        norm = sur.norm.to("cpu", torch.float32)
        self.periodic = tuple(norm.periodic)
        for k in ("x_mean", "x_std", "y_mean", "y_std", "u_center", "u_scale", "play", "lag_index"):
            self.register_buffer(k, getattr(norm, k).clone())
        self.n_play = norm.n_play
        self.n_command = norm.n_command
        self.n_state = norm.n_state
        self.omega_in = norm.omega_in
        self.dt = float(sur.spec.dt)
        self.own_norm = norm if norm.own is not None else None
        """The float32 normalisation with joints on a map in parallel (None: none; CPU, as
        the export runs)."""
        add_end_stops(self, sur)

    def forward(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        z: torch.Tensor | None = None,
        w: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, ...]:
        """See the class docstring."""
        if self.n_state and z is None:
            raise ValueError("this surrogate has command states: pass z")
        if self.omega_in and w is None:
            raise ValueError("this surrogate has a velocity feature: pass w")
        w_in = w if self.omega_in else None
        theta_in, own = theta, self.own_norm
        if own is not None:
            # every sample i: theta_in = where(own, theta_own[i], theta[i]), w_in likewise
            theta_in, w_in = network_inputs(own, theta, z, w_in)
        parts = []
        for j, p in enumerate(self.periodic):
            th = theta_in[..., j : j + 1]
            parts += [torch.sin(th), torch.cos(th)] if p else [th]
        us = (u - self.u_center) / self.u_scale
        parts.append(us)
        if self.n_command:
            assert z is not None
            nj, zc = len(self.periodic), z[..., : self.n_command, :]
            parts.append(command_features(zc, us[..., :nj], self.play, self.lag_index))
        if w_in is not None:
            parts.append(w_in)
        x = torch.cat(parts, dim=-1)
        y = self.net((x - self.x_mean) / self.x_std)
        # omega_net[k+1] = y_std y + y_mean
        omega = y * self.y_std + self.y_mean
        lim = end_stops(self)
        z_out = None
        if own is not None:
            assert z is not None
            # omega[k+1] = where(own, s(u[k - d]), omega_net[k+1]); the own rows move by omega_net
            omega, z_out = own_advance(own, z[:, -1], u[:, -1], omega, dt=self.dt, limits=lim)
        # theta[k+1] = theta[k] + T_s omega[k+1]   (speed bound, end stops)
        theta_next, omega = integrate(theta[:, -1], omega, dt=self.dt, limits=lim)
        return (omega, theta_next) if z_out is None else (omega, theta_next, z_out)


class StatefulOod(nn.Module):
    """A stateful members step (:class:`~.fused.FusedMembersStep`) with the ``ood`` output
    last (:class:`~.uncertainty.OodFlags` on ``theta``, ``u`` and ω[k]).  The inputs after
    ``h``, ``c`` are, in order and when present: ``z``, ``w``, ``omega_prev`` (ω[k] when
    there is no ``w``)."""

    def __init__(self, step: FusedMembersStep, box: OodFlags, *, play: bool, omega_in: bool):
        super().__init__()
        self.step, self.box = step, box
        self.play, self.omega_in = play, omega_in

    def forward(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        e1: torch.Tensor | None = None,
        e2: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, ...]:
        """The step's outputs, then ``ood``."""
        rest = [e for e in (e1, e2) if e is not None]
        z = rest.pop(0) if self.play else None
        w = rest.pop(0) if self.omega_in else None
        omega_k = w if w is not None else rest.pop(0)
        outs = self.step(theta, u, h, c, z, w)
        return (*outs, self.box(theta, u, omega_k))


class VelocityOnly(nn.Module):
    """``forward(theta, u, [h, c,] w)`` of a step without play features: the velocity
    feature is the graph's last input (no ``z`` input in between)."""

    def __init__(self, step: nn.Module) -> None:
        super().__init__()
        self.step = step


class StatefulVelocityOnly(VelocityOnly):
    def forward(  # type: ignore[override]
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        w: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        """:class:`~.fused.FusedStep` with ``z = None``."""
        return self.step(theta, u, h, c, None, w)


class WindowVelocityOnly(VelocityOnly):
    def forward(  # type: ignore[override]
        self, theta: torch.Tensor, u: torch.Tensor, w: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        """:class:`WindowStep` with ``z = None``."""
        return self.step(theta, u, None, w)


def module_members(module: nn.Module) -> int:
    """M of an exported step with the ``omega_members`` output, else 0."""
    inner = getattr(module, "step", module)
    return int(inner.n_member) if isinstance(inner, FusedMembersStep) else 0
