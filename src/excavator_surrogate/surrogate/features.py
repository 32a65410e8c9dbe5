"""Input features, training targets and their normalisation.

Feature layout for a :class:`~excavator_surrogate.spec.MachineSpec` (paper III-B, generalised
to any number of joints): for each joint in order, ``sin θ, cos θ`` if it is periodic, else
``θ``; then every command column scaled by its range, ``us = (u - u_center) / u_scale``: the
joints' commands, then the exogenous inputs' (``spec.inputs``: engine speed, gear ...).  The
width is ``spec.n_feature``.  Optionally (``play`` widths ``b_1..b_P``, ours, not the paper's)
the scaled commands also pass through play (backlash) operators, a Prandtl-Ishlinskii
hysteresis basis: ``z_p[k] = clip(z_p[k-1], us[k] - b_p, us[k] + b_p)`` from ``z_p = 0`` at
rest, and ``(z_p - us) / b_p`` in ``[-1, 1]`` is appended per width and joint (width-major);
play acts on the joints' commands only, not on exogenous inputs.
It says from which side the command last arrived -- the state of a valve's hysteresis, which a
recurrent net cannot learn to remember across a long hold from truncated-BPTT training.
Optionally (``omega_in``, ours) the previous velocity ``omega_in[k] = wrap(theta[k] -
theta[k-1]) / T_s`` [rad/s] (0 at the first sample of an episode, which starts at rest) is
appended per joint: the measured velocity while synced to a machine, the integrated prediction
in a free run.  It is the state of a slow, acceleration-limited flow (a heavy swing), which the
net otherwise has to infer from the small differences of consecutive angle features.
Optionally (``lags`` ``d_1..d_J`` [samples], ours) each joint's scaled command ``d_j`` samples
back, ``us_j[k - d_j]`` (0 before the first sample), is appended before ``omega_in``: what a
delayed static map reads (:func:`.series.with_map_joints`).  Both histories travel in one
command state ``z``, the delay line after the play operators (:mod:`.command_state`).
Features and targets are then standardised with statistics of the training split
(:class:`Normalization`), which travel with the checkpoint.

Data convention: sample ``k`` holds ``theta[k]`` (angle at ``t_k``), ``u[k]`` (command applied
during ``[t_k, t_{k+1})``) and ``omega[k]`` (mean velocity over ``[t_{k-1}, t_k]``).  The
training target is the backward difference of the angle,
``omega_tgt[k] = wrap(theta[k] - theta[k-1]) / T_s`` (``wrap`` only for periodic joints), so
integrating it, ``theta[k+1] = theta[k] + T_s * omega_tgt[k+1]``, reproduces the angles exactly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from ..errors import CheckpointError
from ..spec import MachineSpec
from .angles import omega_in_np, omega_target
from .command_state import (
    command_features,
    command_rows_seq,
    command_rows_step,
    line_from_rest_np,
)
from .features_np import encode_np, play_states_from_rest, scale_commands_np
from .own_angles import N_OWN_ROWS, OwnMap

STD_FLOOR = 1e-3
"""Smallest standard deviation used to scale a feature or target (avoids blowing up constants)."""


@dataclass
class Normalization:
    """Feature and target standardisation computed on the training split.

    ``x_norm = (x - x_mean) / x_std`` for the ``n_feature`` raw features and
    ``y_norm = (omega - y_mean) / y_std`` for the ``n_joint`` velocity targets [rad/s].
    Also carries what :meth:`encode` needs to build features from angles in torch
    (periodic mask, command centre/scale, play widths), so it is the single source of truth.
    """

    x_mean: torch.Tensor
    x_std: torch.Tensor
    y_mean: torch.Tensor
    y_std: torch.Tensor
    periodic: tuple[bool, ...]
    u_center: torch.Tensor
    u_scale: torch.Tensor
    play: torch.Tensor = field(default_factory=lambda: torch.zeros(0))
    """(P,) half-widths of the command play operators [scaled command units]; empty: none."""
    omega_in: bool = False
    """The previous velocity (:func:`.angles.omega_in_np`) is a feature (the last ``n_joint`` columns),
    standardised with the target's ``y_mean`` / ``y_std`` (what a residual head adds)."""
    lags: tuple[int, ...] = ()
    """(n_joint,) command delays ``d_j`` [samples] of the delayed-command features (the
    ``n_joint`` columns before the velocity feature), standardised like the commands; empty:
    none.  Their delay line of ``max(d) + 1`` samples follows the play states in ``z``."""
    own: OwnMap | None = None
    """Joints that report a static map's speed while the network reads its own angle of them
    (:mod:`.own_angles`): two more rows of ``z`` after the command state; None: none."""

    def __post_init__(self) -> None:
        self.periodic_mask = torch.tensor(self.periodic, device=self.u_center.device)
        """(n_joint,) bool: which joints wrap (on the device of the other tensors)."""
        if self.lags and (len(self.lags) != len(self.periodic) or min(self.lags) < 0):
            raise ValueError(f"lags must be one delay >= 0 per joint, got {list(self.lags)}")
        n = len(self.periodic)
        self.lag_index = torch.tensor(
            [self.n_line - 1 - d for d in self.lags], dtype=torch.long, device=self.u_center.device
        )
        """(n_joint,) long: each joint's row ``L - 1 - d_j`` in the delay line (empty: none)."""
        self.n_lag = n if self.lags else 0
        """Number of delayed-command feature columns (``n_joint`` or 0)."""
        if self.own is not None:
            if len(self.own.own) != n:
                raise ValueError(f"the own-angle map has {len(self.own.own)} joints, not {n}")
            far = [d for d in self.own.delay if d >= max(self.n_line, 1)]
            if far:
                raise ValueError(
                    f"the own-angle map reads commands {max(far)} samples back; the command "
                    f"delay line holds {max(self.n_line - 1, 0)}"
                )

    @property
    def n_play(self) -> int:
        """Number P of play operators per joint (0: the paper's features)."""
        return int(self.play.numel())

    @property
    def n_line(self) -> int:
        """Length L of the command delay line (``max(lags) + 1``; 0: no delayed commands)."""
        return max(self.lags) + 1 if self.lags else 0

    @property
    def n_angle(self) -> int:
        """Angle feature columns: 2 per periodic joint (sin, cos), 1 per other joint."""
        return sum(2 if p else 1 for p in self.periodic)

    @property
    def n_command(self) -> int:
        """Rows of the command state proper: the P play operators, then the L-sample delay line."""
        return self.n_play + self.n_line

    @property
    def n_own(self) -> int:
        """Rows after them: the network's own angle and velocity (:mod:`.own_angles`), or 0."""
        return N_OWN_ROWS if self.own is not None else 0

    @property
    def n_state(self) -> int:
        """Rows of ``z``: the P play operators, the L-sample delay line, then the network's own
        angle and velocity when joints follow a map in parallel (:attr:`own`)."""
        return self.n_command + self.n_own

    @property
    def n_feature(self) -> int:
        """Input width: ``spec.n_feature + P * n_joint`` (+ ``n_joint`` with ``lags``, +
        ``n_joint`` with ``omega_in``)."""
        return int(self.x_mean.shape[0])

    @property
    def lag_start(self) -> int:
        """The column of the first delayed-command feature (without them: where they would
        go, before the velocity feature)."""
        return self.n_feature - self.n_lag - (len(self.periodic) if self.omega_in else 0)

    def with_lags(self, lags: Sequence[int]) -> Normalization:
        """A copy with delayed-command features ``lags`` (n_joint,) [samples] added (this one
        must have none): their columns go before the velocity feature, with the statistics
        of the joints' command columns (so the delayed command is standardised like the
        command itself)."""
        if self.lags:
            raise ValueError("with_lags: this normalisation already has delayed commands")
        n = len(self.periodic)
        at = self.lag_start
        src = torch.arange(self.n_angle, self.n_angle + n)

        def grow(a: torch.Tensor) -> torch.Tensor:
            return torch.cat([a[:at], a[src], a[at:]])

        return Normalization(
            x_mean=grow(self.x_mean),
            x_std=grow(self.x_std),
            y_mean=self.y_mean.clone(),
            y_std=self.y_std.clone(),
            periodic=self.periodic,
            u_center=self.u_center.clone(),
            u_scale=self.u_scale.clone(),
            play=self.play.clone(),
            omega_in=self.omega_in,
            lags=tuple(int(d) for d in lags),
            own=self.own,
        )

    def with_own(self, own: OwnMap | None) -> Normalization:
        """A copy whose joints ``own.own`` follow ``own``'s map in parallel (None: none)."""
        dev = self.u_center
        return replace(self, own=None if own is None else own.to(dev.device, dev.dtype))

    @classmethod
    def fit(
        cls,
        thetas: Sequence[np.ndarray],
        us: Sequence[np.ndarray],
        spec: MachineSpec,
        *,
        play: Sequence[float] = (),
        omega_in: bool = False,
    ) -> Normalization:
        """Statistics from lists of per-episode ``(n_step, n_joint)`` angle and command arrays
        (each episode starting at rest, for the play states and the velocity feature)."""
        x = np.concatenate(
            [
                encode_np(
                    t,
                    u,
                    spec,
                    play=play,
                    z=play_states_from_rest(u, spec, play),
                    omega=omega_in_np(t, spec) if omega_in else None,
                )
                for t, u in zip(thetas, us)
            ],
            axis=0,
        )
        y = np.concatenate([omega_target(t, spec)[1:] for t in thetas], axis=0)
        x_std = np.maximum(x.std(axis=0), STD_FLOOR)
        y_std = np.maximum(y.std(axis=0), STD_FLOOR)
        return cls.from_arrays(
            x_mean=x.mean(axis=0),
            x_std=x_std,
            y_mean=y.mean(axis=0),
            y_std=y_std,
            spec=spec,
            play=play,
            omega_in=omega_in,
        )

    @classmethod
    def from_arrays(
        cls,
        *,
        x_mean: Any,
        x_std: Any,
        y_mean: Any,
        y_std: Any,
        spec: MachineSpec,
        play: Sequence[float] | torch.Tensor = (),
        omega_in: bool = False,
        lags: Sequence[int] = (),
    ) -> Normalization:
        """Build from array-likes (checkpoint tensors or NumPy); with ``omega_in`` the last
        ``n_joint`` feature statistics are set to the target's (the velocity feature is
        standardised like the target, so a residual head can add it)."""

        def t(a: Any) -> torch.Tensor:
            return torch.as_tensor(np.asarray(a, dtype=np.float32)).clone()

        widths = t(play).reshape(-1)
        if widths.numel() and not bool(torch.all(widths > 0)):
            raise ValueError(f"play widths must be > 0, got {widths.tolist()}")
        xm, xs = t(x_mean), t(x_std)
        if omega_in:  # the velocity feature in the target's units (a residual head adds it)
            xm[-spec.n_joint :], xs[-spec.n_joint :] = t(y_mean), t(y_std)
        return cls(
            x_mean=xm,
            x_std=xs,
            y_mean=t(y_mean),
            y_std=t(y_std),
            periodic=tuple(spec.periodic),
            u_center=t([c.u_center for c in spec.u_specs]),
            u_scale=t([c.u_scale for c in spec.u_specs]),
            play=widths,
            omega_in=bool(omega_in),
            lags=tuple(int(d) for d in lags),
        )

    def to(self, device: torch.device | str, dtype: torch.dtype = torch.float32) -> Normalization:
        """Copy with every tensor on ``device`` / ``dtype``."""
        kw = {
            k: getattr(self, k).to(device=device, dtype=dtype)
            for k in ("x_mean", "x_std", "y_mean", "y_std", "u_center", "u_scale", "play")
        }
        own = None if self.own is None else self.own.to(device, dtype)
        return Normalization(
            periodic=self.periodic, omega_in=self.omega_in, lags=self.lags, own=own, **kw
        )

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Plain tensors for the checkpoint (``omega_in`` only when set, so checkpoints without
        the velocity feature stay as they were)."""
        out = {
            k: getattr(self, k).detach().cpu().float()
            for k in ("x_mean", "x_std", "y_mean", "y_std", "play")
        }
        if self.omega_in:
            out["omega_in"] = torch.tensor(1.0)
        if self.lags:
            out["lags"] = torch.tensor(self.lags, dtype=torch.float32)
        if self.own is not None:
            out.update(self.own.state_dict())
        return out

    @classmethod
    def from_state_dict(cls, d: dict[str, Any], spec: MachineSpec) -> Normalization:
        """Inverse of :meth:`state_dict`; checks sizes against ``spec`` (no ``play`` /
        ``omega_in`` entry: a checkpoint from before those features, none)."""
        try:
            norm = cls.from_arrays(
                x_mean=d["x_mean"],
                x_std=d["x_std"],
                y_mean=d["y_mean"],
                y_std=d["y_std"],
                spec=spec,
                play=d.get("play", ()),
                omega_in=bool(float(d.get("omega_in", 0.0))),
                lags=[round(float(v)) for v in torch.as_tensor(d.get("lags", ())).reshape(-1)],
            )
            own = OwnMap.from_state_dict(d)
            if own is not None:
                norm = norm.with_own(own)
        except (KeyError, TypeError, ValueError, RuntimeError) as e:
            raise CheckpointError(f"normalisation entry is malformed ({e})") from e
        n_feature = spec.n_feature + (norm.n_play + norm.omega_in) * spec.n_joint + norm.n_lag
        if norm.x_mean.shape != (n_feature,) or norm.y_mean.shape != (spec.n_joint,):
            raise CheckpointError(
                f"normalisation sizes {tuple(norm.x_mean.shape)}/{tuple(norm.y_mean.shape)} do not match "
                f"the spec ({n_feature} features, {spec.n_joint} joints)"
            )
        return norm

    # ---- play operators ---------------------------------------------------------------------

    def play_rest(self, n_batch: int) -> torch.Tensor:
        """Command states at rest: zeros ``(n_batch, P + L, n_joint)`` (P + L may be 0)."""
        return self.u_scale.new_zeros(n_batch, self.n_state, len(self.periodic))

    def play_update(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Command states after commands ``u: (..., n_u)`` (the joints' columns drive them);
        ``z: (..., P + L [+ 2], n_joint)``: the play operators, then the delay line (then the
        network's own angle and velocity, passed through: :meth:`own_advance` moves them)."""
        if not self.n_command:
            return z
        return command_rows_step(z, self._joint_commands(u), self.play, self.n_command)

    def play_seq(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Command states after each of ``u: (n_batch, n_step, n_u)`` from ``z: (n_batch,
        P + L [+ 2], n_joint)`` (:meth:`play_update` one sample at a time, to the bit: the
        delay line is a window of the commands, only play operators loop); returns
        ``(n_batch, n_step, P + L [+ 2], n_joint)``."""
        return command_rows_seq(z, self._joint_commands(u), self.play, self.n_command)

    def _joint_commands(self, u: torch.Tensor) -> torch.Tensor:
        """The joints' scaled commands ``us = (u - u_center) / u_scale``, which drive the
        command state: ``u: (..., n_u)`` -> ``(..., n_joint)``."""
        nj = len(self.periodic)
        return (u[..., :nj] - self.u_center[:nj]) / self.u_scale[:nj]

    # ---- velocity feature -------------------------------------------------------------------

    def velocity(self, theta: torch.Tensor, theta_prev: torch.Tensor, dt: float) -> torch.Tensor:
        """The velocity feature from measured angles, ``wrap(theta - theta_prev) / T_s``
        (``wrap`` on periodic joints); ``theta``, ``theta_prev``: (..., n_joint) [rad] ->
        (..., n_joint) [rad/s]."""
        d = theta - theta_prev
        # wrap(d) = (d + pi) mod 2 pi - pi
        d = torch.where(
            self.periodic_mask, torch.remainder(d + math.pi, 2.0 * math.pi) - math.pi, d
        )
        return d / dt

    def velocity_seq(self, theta: torch.Tensor, dt: float) -> torch.Tensor:
        """Torch twin of :func:`.angles.omega_in_np` along axis -2: ``theta: (..., n_step, n_joint)``
        [rad] -> (..., n_step, n_joint) [rad/s], sample 0 at rest (0)."""
        w = self.velocity(theta[..., 1:, :], theta[..., :-1, :], dt)
        return torch.cat([torch.zeros_like(theta[..., :1, :]), w], dim=-2)

    # ---- torch encoding (differentiable in theta) -------------------------------------------

    def encode(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        z: torch.Tensor | None = None,
        omega: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Normalised features from angles and commands.

        Args:
            theta: (..., n_joint) angles [rad].
            u: (..., n_u) commands [command units] (joints', then exogenous inputs').
            z: (..., P + L, n_joint) command states after ``u`` (:meth:`play_update`); needed
                when ``n_state > 0``, ignored otherwise.
            omega: (..., n_joint) velocity input ``wrap(theta[k] - theta[k-1]) / T_s``
                [rad/s]; needed with ``omega_in``, ignored otherwise.

        Returns:
            (..., n_feature) normalised features (same layout as :func:`.features_np.encode_np`).
        """
        out = [self.angle_raw(theta), self.command_raw(u, z)]
        if self.omega_in:
            if omega is None:
                raise ValueError("encode: this normalisation has a velocity feature; pass omega")
            out.append(omega)
        x = torch.cat(out, dim=-1)
        return (x - self.x_mean) / self.x_std

    def angle_raw(self, theta: torch.Tensor) -> torch.Tensor:
        """The angle columns of :meth:`encode` before normalisation: ``theta: (..., n_joint)``
        [rad] -> ``(..., n_angle)``, sin and cos of a periodic joint, else the angle."""
        parts = []
        for j, p in enumerate(self.periodic):
            th = theta[..., j]
            if p:
                parts += [torch.sin(th), torch.cos(th)]
            else:
                parts.append(th)
        return torch.stack(parts, dim=-1)

    def command_raw(self, u: torch.Tensor, z: torch.Tensor | None) -> torch.Tensor:
        """The command columns of :meth:`encode` before normalisation (they do not depend on
        the angles): the scaled commands ``us = (u - u_center) / u_scale`` of ``u: (..., n_u)``,
        then the features of the command state ``z: (..., P + L, n_joint)`` (if any)."""
        us = (u - self.u_center) / self.u_scale
        if not self.n_command:
            return us
        if z is None:
            what = "play features" if self.n_play else "delayed commands"
            raise ValueError(f"encode: this normalisation has {what}; pass z")
        nj, zc = len(self.periodic), z[..., : self.n_command, :]
        return torch.cat(
            [us, command_features(zc, us[..., :nj], self.play, self.lag_index)], dim=-1
        )

    def encode_np(
        self,
        theta: np.ndarray,
        u: np.ndarray,
        spec: MachineSpec,
        z: np.ndarray | None = None,
        omega: np.ndarray | None = None,
    ) -> np.ndarray:
        """NumPy twin of :meth:`encode` (float64), used by reference implementations."""
        if self.omega_in and omega is None:
            raise ValueError("encode_np: this normalisation has a velocity feature; pass omega")
        q, lag = self.n_play, None
        if self.n_line:
            if z is None:
                raise ValueError("encode_np: this normalisation has delayed commands; pass z")
            idx = self.lag_index.cpu().numpy()
            lag = np.asarray(z)[..., q:, :][..., idx, np.arange(len(idx))]
        x = encode_np(
            theta,
            u,
            spec,
            play=self.play_widths,
            z=None if z is None else np.asarray(z)[..., :q, :],
            lag=lag,
            omega=omega if self.omega_in else None,
        )
        return (x - self.x_mean.cpu().double().numpy()) / self.x_std.cpu().double().numpy()

    @property
    def play_widths(self) -> tuple[float, ...]:
        """The play half-widths as Python floats."""
        return tuple(float(b) for b in self.play.cpu().double())

    def play_from_rest_np(self, u: np.ndarray, spec: MachineSpec) -> np.ndarray | None:
        """Command states ``(..., n_step, P + L, n_joint)`` of commands ``u: (..., n_step,
        n_u)`` from rest (plain loops), or None without play features or delayed commands."""
        z = play_states_from_rest(u, spec, self.play_widths)
        if not self.n_line:
            return z
        line = line_from_rest_np(scale_commands_np(u, spec)[..., : spec.n_joint], self.n_line)
        return line if z is None else np.concatenate([z, line], axis=-2)

    def omega(self, y: torch.Tensor) -> torch.Tensor:
        """Physical velocity [rad/s] from normalised model output ``(..., n_joint)``."""
        return y * self.y_std + self.y_mean

    def target(self, omega: torch.Tensor) -> torch.Tensor:
        """Normalised target from velocity [rad/s] ``(..., n_joint)``."""
        return (omega - self.y_mean) / self.y_std
