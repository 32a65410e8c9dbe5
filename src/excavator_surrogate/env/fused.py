"""The single-step surrogate with its encoding folded into the weights (:class:`FusedStep`).

:class:`FusedStep` maps raw angles and commands straight to angular velocities,
``(theta, u, h, c) -> (omega, theta_next, h', c')``: the feature encoding and the feature /
target normalisation are folded into the first and last layers.  It is written with plain
matmuls and pointwise ops, so it exports to ONNX as is (see :mod:`.export`), and
:class:`~.engine.SurrogateEngine` steps its weights.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.angles import envelope_inward, integrate
from ..surrogate.command_state import command_features, command_rows_step, delayed_commands
from ..surrogate.ensemble import member_head
from ..surrogate.features import Normalization
from ..surrogate.model import Surrogate
from ..surrogate.own_angles import network_inputs, own_advance, own_members
from ..surrogate.parallel import own_gain_dev
from ..surrogate.prior import SpeedPrior
from .inputs import ActionLayout


def rest_command(spec: MachineSpec) -> np.ndarray:
    """The at-rest command (n_u,): 0 clipped into each joint's ``[u_min, u_max]``, then each
    exogenous input at the centre of its range (an env with fixed inputs overrides them)."""
    return ActionLayout(spec).rest()


def _fold_input(sur: Surrogate) -> tuple[np.ndarray, np.ndarray]:
    """Matrix ``M`` (n_feature, n_raw) and offset ``e`` (n_feature,) with
    ``x_norm = M @ r + e`` for raw features ``r = [theta (J), sin θ_p, cos θ_p, u (n_u), f,
    w]`` (``u``: the joints' commands then the exogenous inputs; ``f``: the Q * J play
    features ``(z - us) / b`` and the J delayed scaled commands, if any; ``w``: the J velocity
    features [rad/s], if any)."""
    spec, norm = sur.spec, sur.norm
    n_joint, n_u = spec.n_joint, spec.n_u
    per = [k for k, p in enumerate(spec.periodic) if p]
    n_per = len(per)
    n_play = norm.n_play * n_joint + norm.n_lag
    n_w = n_joint if norm.omega_in else 0
    n_raw = n_joint + 2 * n_per + n_u + n_play + n_w
    m = norm.x_mean.double().cpu().numpy()
    s = norm.x_std.double().cpu().numpy()
    mat = np.zeros((norm.n_feature, n_raw))
    off = -m / s
    col = 0
    for k, js in enumerate(spec.joints):
        if js.periodic:
            p = per.index(k)
            mat[col, n_joint + p] = 1.0 / s[col]
            mat[col + 1, n_joint + n_per + p] = 1.0 / s[col + 1]
            col += 2
        else:
            mat[col, k] = 1.0 / s[col]
            col += 1
    for k, js in enumerate(spec.u_specs):
        mat[col, n_joint + 2 * n_per + k] = 1.0 / (js.u_scale * s[col])
        off[col] += -js.u_center / js.u_scale / s[col]
        col += 1
    for k in range(n_play + n_w):
        mat[col, n_joint + 2 * n_per + n_u + k] = 1.0 / s[col]
        col += 1
    return mat, off


def add_play(module: nn.Module, sur: Surrogate) -> None:
    """Register the surrogate's command state on ``module``: float32 buffers ``play`` (Q,)
    half-widths, ``u_center`` / ``u_scale`` (n_u,), the long buffer ``lag_index`` (J,) of the
    delayed commands (empty: none); ``module.n_play`` = Q, ``module.n_command`` = Q + L rows of
    the command state, ``module.n_state`` the rows of ``z`` (+ 2 with joints on a map in
    parallel, :mod:`~excavator_surrogate.surrogate.own_angles`; 0: none)."""
    norm = sur.norm.to("cpu", torch.float32)
    module.n_play = norm.n_play
    module.n_command = norm.n_command
    module.n_state = norm.n_state
    for k in ("play", "u_center", "u_scale", "lag_index"):
        module.register_buffer(k, getattr(norm, k).clone())


def play_and_features(
    module: nn.Module | Normalization, z: torch.Tensor, u: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Command states after ``u`` and their features, with the buffers of :func:`add_play`
    (or the same-named tensors of a :class:`Normalization`).

    Args:
        z: (..., Q + L [+ 2], n_joint) command states before ``u``: the play operators, then
            the delay line of the delayed commands (L = 0: none), then (joints on a map in
            parallel) the network's own angle and velocity, passed through.
        u: (..., n_u) commands [command units]; the first ``n_joint`` (the joints') drive
            the play operators and the line, exogenous inputs do not.

    Returns:
        ``z_new`` (as ``z``) and the features: ``(z_new - us) / b`` (..., Q * n_joint), then
        with a line each joint's delayed scaled command (..., n_joint); None without a
        command state proper (Q = L = 0).
    """
    nj, c = z.shape[-1], module.n_command
    if not c:  # only the network's own angle and velocity: no command features
        return z, None
    us = (u[..., :nj] - module.u_center[:nj]) / module.u_scale[:nj]
    z = command_rows_step(z, us, module.play, c)
    return z, command_features(z[..., :c, :], us, module.play, module.lag_index)


def _prior_lagged(sur: Surrogate) -> list[bool]:
    """(n_joint,) for a network with a speed prior: whether joint ``j``'s map reads its
    delayed-command feature (column ``lag_start + j``) rather than its current command
    (column ``n_angle + j``); a network given delayed commands for a map in parallel
    (:func:`~excavator_surrogate.surrogate.parallel.with_parallel_map`) keeps its prior on the
    current ones."""
    norm, n_angle = sur.norm, sur.spec.n_angle_feature
    cols = [int(c) for c in sur.net.prior.cols.tolist()]
    out = []
    for j, col in enumerate(cols):
        if norm.n_lag and col == norm.lag_start + j:
            out.append(True)
        elif col == n_angle + j:
            out.append(False)
        else:
            raise ConfigError(
                f"model '{sur.name}': the speed prior of joint {sur.spec.names[j]} reads "
                f"feature column {col}, neither its command nor its delayed command"
            )
    return out


def add_end_stops(module: nn.Module, sur: Surrogate) -> None:
    """Register the surrogate's envelope on ``module`` as float32 buffers ``theta_lo`` /
    ``theta_hi`` (n_joint,) [rad] and ``omega_max`` (n_joint,) [rad/s], each rounded inward
    (:func:`~excavator_surrogate.surrogate.angles.envelope_inward`) and None when the
    surrogate has none (they then stay out of the graph)."""
    lim = sur.limits_np()
    stops = None if lim is None else envelope_inward(lim, dtype=torch.float32)
    for name, k in (("theta_lo", 0), ("theta_hi", 1), ("omega_max", 2)):
        has = stops is not None and k < len(stops)
        module.register_buffer(name, stops[k] if has else None)


def end_stops(module: nn.Module) -> tuple[torch.Tensor, ...] | None:
    """The ``(theta_lo, theta_hi[, omega_max])`` buffers of :func:`add_end_stops`, or None."""
    lo, hi, w = module.theta_lo, module.theta_hi, module.omega_max
    if lo is None:
        return None
    return (lo, hi) if w is None else (lo, hi, w)  # type: ignore[return-value]


class _Parts(NamedTuple):
    """One :meth:`FusedStep.step_parts`: the step's outputs and what a members' step reuses."""

    omega: torch.Tensor
    """(n_batch, n_joint) ω̂[k+1] [rad/s] after the speed bound and end stops."""
    theta_next: torch.Tensor
    """(n_batch, n_joint) θ[k+1] [rad]."""
    h: torch.Tensor
    """(n_layer, n_batch, hidden) new recurrent state."""
    c: torch.Tensor
    """(n_layer, n_batch, hidden) new cell state (GRU: passed through)."""
    z: torch.Tensor | None
    """(n_batch, Q + L [+ 2], n_joint) the new command state (None without one)."""
    base: torch.Tensor | None
    """(n_batch, n_joint) [rad/s] what the head's output was added to (:meth:`FusedStep.base`
    of the velocity feature the network read), or None."""
    speed: torch.Tensor
    """(n_batch, n_joint) [rad/s] the speed integrated, before the speed bound and end stops
    (the map's on joints on a map in parallel)."""


class FusedStep(nn.Module):
    """One closed-loop step with encoding and normalisation folded into the weights.

    ``forward(theta, u, h, c[, z])``:

    - ``theta``: (n_batch, n_joint) angles θ[k] [rad] (periodic joints wrapped or not);
    - ``u``: (n_batch, n_u) commands u[k] [command units] (joints', then exogenous inputs');
    - ``h``, ``c``: (n_layer, n_batch, hidden) recurrent state (``c`` unused and passed
      through for GRU cells);
    - ``z``: (n_batch, Q + L [+ 2], n_joint) command states before ``u`` (only if the
      surrogate has ``Q = n_play > 0`` play features, an ``L``-sample delay line of delayed
      commands or joints on a static map in parallel, whose two rows, the network's own angle
      [rad] and velocity [rad/s] of every joint, come last:
      :mod:`excavator_surrogate.surrogate.own_angles`);
    - ``w``: (n_batch, n_joint) velocity feature of sample k [rad/s] (only if the surrogate
      has one, ``omega_in``): the ``omega`` this step returned last time, or the measured
      ``wrap(θ[k] - θ[k-1]) / T_s`` after a measured angle.

    Returns ``omega`` (n_batch, n_joint) = ω̂[k+1] [rad/s], ``theta_next`` = θ + T_s·ω̂
    [rad] (clipped to the end stops if the surrogate has them), the new ``h``, ``c`` and,
    with command states, the new ``z``.  With a speed prior (``ModelConfig.prior``) the head's
    output is added to the prior's speed of ``u`` (:meth:`prior_speed`; of the delayed
    command for a joint whose map has a delay).  (``omega`` is the next step's ``w``.)  With
    joints on a static map in parallel (``norm.own``) the network reads its own angle and
    velocity of them from ``z``
    (:func:`~excavator_surrogate.surrogate.own_angles.network_inputs`), ``omega`` there is the
    map's speed, and ``z``'s own rows move by the network's
    (:func:`~excavator_surrogate.surrogate.own_angles.own_advance`).  Only LSTM/GRU
    surrogates can be fused.
    """

    def __init__(self, sur: Surrogate) -> None:
        super().__init__()
        net = sur.net
        cell = sur.model_cfg.cell
        if cell not in ("lstm", "gru"):
            raise ConfigError(f"only LSTM/GRU surrogates can be stepped statefully, not '{cell}'")
        spec = sur.spec
        self.cell = cell
        self.n_layer = sur.model_cfg.n_layer
        add_end_stops(self, sur)
        add_play(self, sur)
        self.omega_in = bool(sur.norm.omega_in)
        self.hidden = sur.model_cfg.hidden
        self.n_joint = spec.n_joint
        self.dt = float(spec.dt)
        per = [k for k, p in enumerate(spec.periodic) if p]
        self.register_buffer("periodic_idx", torch.tensor(per, dtype=torch.long), persistent=False)
        self.has_periodic = bool(per)
        self.own_norm: Normalization | None = (
            None if sur.norm.own is None else sur.norm.to("cpu", torch.float32)
        )
        """With joints on a static map in parallel: a float32 copy of the normalisation, for
        :func:`~excavator_surrogate.surrogate.own_angles.network_inputs` / ``own_advance``
        (moved to the buffers' device on use, :meth:`own`); None without."""
        mat, off = _fold_input(sur)
        rnn = net.rnn
        f32 = torch.float32

        def p(name: str) -> np.ndarray:
            return getattr(rnn, name).detach().double().cpu().numpy()

        self.w_ih = nn.ParameterList()
        self.w_hh = nn.ParameterList()
        self.b_ih = nn.ParameterList()
        self.b_hh = nn.ParameterList()
        for layer in range(self.n_layer):
            w_ih = p(f"weight_ih_l{layer}")
            b_ih = p(f"bias_ih_l{layer}")
            if layer == 0:
                b_ih = b_ih + w_ih @ off
                w_ih = w_ih @ mat
            for lst, a in (
                (self.w_ih, w_ih),
                (self.w_hh, p(f"weight_hh_l{layer}")),
                (self.b_ih, b_ih),
                (self.b_hh, p(f"bias_hh_l{layer}")),
            ):
                lst.append(nn.Parameter(torch.tensor(a, dtype=f32), requires_grad=False))
        lin1, lin2 = net.head[0], net.head[2]
        y_std = sur.norm.y_std.double().cpu().numpy()
        y_mean = sur.norm.y_mean.double().cpu().numpy()
        w2 = lin2.weight.detach().double().cpu().numpy() * y_std[:, None]
        # omega = y_std y + y_mean; residual: y_std head + w (the velocity feature, raw);
        # prior: y_std head + s(u) (the speed prior of the raw commands)
        self.residual = bool(sur.model_cfg.residual)
        self.additive = self.residual or bool(sur.model_cfg.prior)
        """The head's output is added to a base (velocity feature or speed prior): no y_mean."""
        b2 = lin2.bias.detach().double().cpu().numpy() * y_std + (0.0 if self.additive else y_mean)
        prior = getattr(net, "prior", None)
        self.prior: SpeedPrior | None = (
            None if prior is None else copy.deepcopy(prior).float().cpu()
        )
        """The network's speed prior (its map reads the raw commands here: :meth:`prior_speed`)."""
        lagged = [] if self.prior is None else _prior_lagged(sur)
        self.prior_lagged = any(lagged)
        """The prior's map reads some joint's delayed command (from the delay line of ``z``)."""
        self.register_buffer(
            "prior_lag_mask", torch.tensor(lagged, dtype=torch.bool), persistent=False
        )
        self.w1 = nn.Parameter(lin1.weight.detach().float().clone(), requires_grad=False)
        self.b1 = nn.Parameter(lin1.bias.detach().float().clone(), requires_grad=False)
        self.w2 = nn.Parameter(torch.tensor(w2, dtype=f32), requires_grad=False)
        self.b2 = nn.Parameter(torch.tensor(b2, dtype=f32), requires_grad=False)

    @property
    def n_raw(self) -> int:
        """Width of the raw feature vector ``[theta, sin θ_p, cos θ_p, u]``."""
        return int(self.w_ih[0].shape[1])

    def features(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        f: torch.Tensor | None = None,
        w: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Raw features ``[theta, sin θ_p, cos θ_p, u, f, w]`` (n_batch, n_raw), float32, with
        ``f`` the features of :func:`play_and_features` (None without them) and ``w``
        the velocity feature [rad/s] (None without one)."""
        tail = [u] + ([] if f is None else [f]) + ([] if w is None else [w])
        if self.has_periodic:
            tp = theta.index_select(-1, self.periodic_idx)
            return torch.cat([theta, torch.sin(tp), torch.cos(tp), *tail], dim=-1)
        return torch.cat([theta, *tail], dim=-1)

    def prior_speed(self, u: torch.Tensor, z: torch.Tensor | None = None) -> torch.Tensor | None:
        """The speed prior's ``s(u)`` (n_batch, n_joint) [rad/s] of the commands ``u``
        (n_batch, n_u) [command units] (a joint whose map reads its delayed-command feature:
        of ``u_j[k - d_j]``, read from the delay line of ``z`` (n_batch, Q + L [+ 2],
        n_joint) after ``u``); None without a prior."""
        if self.prior is None:
            return None
        nj = self.n_joint
        if not self.prior_lagged:
            return self.prior.speed(u[..., :nj])
        if z is None:
            raise ValueError("this surrogate's map reads delayed commands: pass z")
        # u_j[k - d_j] = us_j[k - d_j] u_scale_j + u_center_j   (from the delay line)
        u_d = (
            delayed_commands(z, self.play, self.lag_index) * self.u_scale[:nj] + self.u_center[:nj]
        )
        return self.prior.speed(torch.where(self.prior_lag_mask, u_d, u[..., :nj]))

    def base(
        self, u: torch.Tensor, w: torch.Tensor | None, z: torch.Tensor | None = None
    ) -> torch.Tensor | None:
        """What the head's output is added to: the velocity feature ``w`` (residual head),
        the prior's speed of ``u`` (speed prior; ``z`` the command states after ``u``, for a
        delayed map), else None."""
        if self.residual:
            return w
        return self.prior_speed(u, z)

    def head(self, out: torch.Tensor) -> torch.Tensor:
        """Angular velocity [rad/s] from the last layer's output (n_batch, hidden) (with a
        residual head or a speed prior: the part to be added to :meth:`base`)."""
        z = torch.relu(torch.nn.functional.linear(out, self.w1, self.b1))
        return torch.nn.functional.linear(z, self.w2, self.b2)

    def own(self) -> Normalization | None:
        """The float32 normalisation copy with the map in parallel (:attr:`own_norm`) on the
        buffers' device, or None without joints on such a map."""
        norm = self.own_norm
        if norm is not None and norm.u_center.device != self.u_center.device:
            norm = self.own_norm = norm.to(self.u_center.device, torch.float32)
        return norm

    def step_parts(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        z: torch.Tensor | None = None,
        w: torch.Tensor | None = None,
    ) -> _Parts:
        """One step (the arguments as :meth:`forward`'s), with the values a members' step
        needs besides the outputs (:class:`_Parts`)."""
        if self.n_state and z is None:
            raise ValueError("this surrogate has command states: pass z")
        if self.omega_in and w is None:
            raise ValueError("this surrogate has a velocity feature: pass w")
        f = None
        if self.n_state:
            z, f = play_and_features(self, z, u)
        else:
            z = None
        w_in = w if self.omega_in else None
        theta_in, norm = theta, self.own()
        if norm is not None:
            # theta_in = where(own, theta_own[k], theta[k]);  w_in = where(own, omega_own[k], w)
            theta_in, w_in = network_inputs(norm, theta, z, w_in)
        inp = self.features(theta_in, u, f, w_in)
        hs, cs = [], []
        for layer in range(self.n_layer):
            h_l, c_l = h[layer], c[layer]
            gi = torch.nn.functional.linear(inp, self.w_ih[layer], self.b_ih[layer])
            gh = torch.nn.functional.linear(h_l, self.w_hh[layer], self.b_hh[layer])
            if self.cell == "lstm":
                i, f, g, o = (gi + gh).chunk(4, dim=-1)
                c_l = torch.sigmoid(f) * c_l + torch.sigmoid(i) * torch.tanh(g)
                h_l = torch.sigmoid(o) * torch.tanh(c_l)
            else:
                ir, iz, in_ = gi.chunk(3, dim=-1)
                hr, hz, hn = gh.chunk(3, dim=-1)
                r = torch.sigmoid(ir + hr)
                upd = torch.sigmoid(iz + hz)
                n = torch.tanh(in_ + r * hn)
                h_l = (1.0 - upd) * n + upd * h_l
            hs.append(h_l)
            cs.append(c_l)
            inp = h_l
        omega = self.head(inp)
        base = self.base(u, w_in, z)
        if base is not None:
            # omega_net[k+1] = base + head
            omega = omega + base
        lim = end_stops(self)
        if norm is not None:
            assert z is not None
            # omega[k+1] = where(own, s(u[k - d]), omega_net[k+1]); z's own rows move by omega_net
            omega, z = own_advance(norm, z, u, omega, dt=self.dt, limits=lim)
        speed = omega
        # theta[k+1] = theta[k] + T_s omega[k+1]   (speed bound, end stops)
        theta_next, omega = integrate(theta, omega, dt=self.dt, limits=lim)
        return _Parts(omega, theta_next, torch.stack(hs), torch.stack(cs), z, base, speed)

    def forward(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        z: torch.Tensor | None = None,
        w: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, ...]:
        """See the class docstring."""
        p = self.step_parts(theta, u, h, c, z, w)
        if p.z is not None:
            return p.omega, p.theta_next, p.h, p.c, p.z
        return p.omega, p.theta_next, p.h, p.c


class FusedMembersStep(FusedStep):
    """:class:`FusedStep` of a merged seed ensemble with one more output, last:
    ``omega_members`` (M, n_batch, n_joint) [rad/s], each member's velocity from the head
    activations of the same call (:class:`~excavator_surrogate.surrogate.ensemble.MemberHead`
    folded with the output scale)."""

    def __init__(self, sur: Surrogate) -> None:
        super().__init__(sur)
        head = member_head(sur)
        if head is None:
            raise ConfigError(
                f"model '{sur.name}' has no ensemble members: a single network has no "
                "uncertainty to export (train a seed ensemble, or export without it)"
            )
        w2m, b2m, map_dev = head.folded(sur.norm, additive=self.additive)
        self.n_member = head.n_member
        self.register_buffer("w2m", w2m.cpu())  # (M, f_tot, n_joint)
        self.register_buffer("b2m", b2m.cpu())  # (M, 1, n_joint)
        # a static-map joint: member m's base is (1 + map_dev[m]) s(u) (None: no such joint)
        self.map_dev: torch.Tensor | None
        if map_dev is None:
            self.map_dev = None
        else:
            self.register_buffer("map_dev", map_dev.cpu())
        # a joint on a map in parallel: member m drives it with gain 1 + own_dev[m] (None: none)
        self.own_dev: torch.Tensor | None
        if sur.norm.own is None:
            self.own_dev = None
        else:
            # (M, n_joint), 0 off the map's joints
            self.register_buffer("own_dev", own_gain_dev(sur).float())
        self._a: torch.Tensor | None = None

    def head(self, out: torch.Tensor) -> torch.Tensor:
        """As :meth:`FusedStep.head`, keeping the activations for the members."""
        self._a = torch.relu(torch.nn.functional.linear(out, self.w1, self.b1))
        return torch.nn.functional.linear(self._a, self.w2, self.b2)

    def forward(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        z: torch.Tensor | None = None,
        w: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, ...]:
        """:class:`FusedStep`'s outputs, then ``omega_members``."""
        p = self.step_parts(theta, u, h, c, z, w)
        assert self._a is not None
        # omega_m = a @ w2m[m] + b2m[m]   (M, n_batch, n_joint)
        om_m = torch.matmul(self._a.unsqueeze(0), self.w2m) + self.b2m
        if p.base is not None:
            # omega_m += base   (the velocity feature the network read, or s(u))
            om_m = om_m + p.base
            if self.map_dev is not None:  # the base is the speed prior's s(u)
                # omega_m += map_dev[m] s(u)
                om_m = om_m + self.map_dev * p.base
        norm = self.own()
        if norm is not None and self.own_dev is not None:
            # omega_m = where(own, (1 + own_dev[m]) s(u[k - d]), omega_m)
            om_m = own_members(norm, om_m, p.speed, self.own_dev)
        outs = (p.omega, p.theta_next, p.h, p.c) + (() if p.z is None else (p.z,))
        return (*outs, om_m)
