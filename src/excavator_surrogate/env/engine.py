"""Batched, allocation-light closed-loop engine behind the surrogate environments.

:class:`SurrogateEngine` steps ``n_envs`` copies of a surrogate in one torch batch:

- **stateful** checkpoints (``mode="stateful"``) are stepped one sample at a time carrying
  ``(h, c)``, through the folded weights' :class:`~.kernels.RecurrentKernel` (cell ops, a
  folded ``nn.LSTM``/``nn.GRU`` or a merged ensemble's members, by batch size);
- **windowed** checkpoints re-run their ``W``-sample window every step from a zero state, as
  they were trained, from a rolling buffer (a doubled ring buffer: no copies per step).

Warm-up after a reset is "at rest": ``W - 1`` samples with the angle held at ``theta0`` and
``u = 0`` (clipped into the command range), exactly what
:class:`~excavator_surrogate.surrogate.rollout.ClosedLoop` does with a constant history.
Resets are masked: only the envs in ``mask`` get new angles and a fresh warm-up state.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch

from ..devices import NoOp, OneThread, resolve_device
from ..errors import ConfigError
from ..surrogate.angles import envelope_inward, integrate
from ..surrogate.model import Surrogate
from ..surrogate.own_angles import network_inputs, own_advance, own_members, own_start
from ..surrogate.parallel import own_gain_dev
from ..surrogate.rollout import ClosedLoop
from .fused import FusedStep, play_and_features, rest_command
from .kernels import Impl, RecurrentKernel, check_impl
from .uncertainty import StepUncertainty

Mode = Literal["windowed", "stateful"]

SINGLE_THREAD_MAX_BATCH = 128
"""Below this batch size a step runs with ONE torch thread (restored afterwards): tiny matmuls
do not gain from threads, and on a shared machine OpenMP barriers waiting for descheduled
threads made small-batch steps up to 10x slower."""


class SurrogateEngine:
    """``n_envs`` surrogate copies stepped in one torch batch, with masked resets.

    Args:
        sur: the loaded surrogate (:func:`~excavator_surrogate.surrogate.checkpoint.load_checkpoint`).
        n_envs: batch size.
        device: torch device for the state and the network (``cpu``, ``cuda[:N]``, ``auto``).
        mode: ``"stateful"`` or ``"windowed"``; default: the checkpoint's training mode.
        impl: stateful implementation: ``"cell"`` (per-layer cell ops), ``"module"`` (folded
            ``nn.LSTM``), ``"members"`` (a merged LSTM ensemble's members as one batched
            matmul, :mod:`~excavator_surrogate.surrogate.member_lstm`) or ``"auto"``
            (members from :data:`~.kernels.MEMBERS_MIN_BATCH` envs on when the surrogate is such an
            ensemble, else module from
            :data:`~.kernels.MODULE_MIN_BATCH` envs on, else cell).
        uncertainty: also track the members' spread and the out-of-distribution flags
            (:class:`~.uncertainty.StepUncertainty`, in :attr:`unc`): the members' velocities
            come from the same network call, their angle deviations are per-env state.

    State: ``theta`` (n_envs, n_joint) float64 [rad]; ``h``, ``c`` (n_layer, n_envs, hidden)
    (stateful; ``impl="members"``: (n_layer, M, n_envs, hidden / M), see
    :meth:`dense_state`) or a ring buffer of normalised features (windowed); ``z`` (n_envs,
    Q, n_joint) play states of the commands (Q = 0 unless the surrogate has play features);
    with a velocity feature (``norm.omega_in``), ``w`` (n_envs, n_joint) float64 [rad/s], the
    velocity feature of the current sample; ``theta_prev`` (n_envs, n_joint) float64 [rad],
    the angle the last step started from (:meth:`observe` turns a measured angle into the
    measured velocity, the velocity feature's and the OOD flags' ω[k]).
    """

    def __init__(
        self,
        sur: Surrogate,
        *,
        n_envs: int,
        device: str | torch.device = "cpu",
        mode: Mode | None = None,
        impl: Impl = "auto",
        uncertainty: bool = False,
    ) -> None:
        if n_envs < 1:
            raise ConfigError(f"n_envs must be >= 1, got {n_envs}")
        self.mode: Mode = mode or sur.mode
        if self.mode not in ("windowed", "stateful"):
            raise ConfigError(f"mode must be 'windowed' or 'stateful', got {self.mode!r}")
        check_impl(impl)
        self.device = resolve_device(device)
        self.sur = sur.to(self.device, torch.float32).eval()
        self.spec = sur.spec
        self.n_envs = int(n_envs)
        self.window = int(sur.window)
        self.dt = float(self.spec.dt)
        self.u_rest = rest_command(self.spec)
        self._threads = OneThread() if self.n_envs < SINGLE_THREAD_MAX_BATCH else NoOp()
        n_joint = self.spec.n_joint
        self.theta = torch.zeros(self.n_envs, n_joint, dtype=torch.float64, device=self.device)
        self.norm = sur.norm.to(self.device, torch.float32)
        self.z = torch.zeros(self.n_envs, self.norm.n_state, n_joint, device=self.device)
        self.omega_in = bool(self.norm.omega_in)
        self.w = torch.zeros_like(self.theta)
        self.theta_prev = torch.zeros_like(self.theta)
        lim = sur.limits_np()  # the float64 angles stop at the spec's own limits
        self._limits = (
            None if lim is None else envelope_inward(lim, dtype=torch.float64, device=self.device)
        )
        self._own_dev = (
            None if self.norm.own is None else own_gain_dev(sur).to(self.device, torch.float32)
        )
        """Joints on a map in parallel: the members' gain deviations (M, n_joint)
        (:func:`~excavator_surrogate.surrogate.parallel.own_gain_dev`), or None."""
        if self.mode == "stateful":
            if sur.model_cfg.cell not in ("lstm", "gru"):
                raise ConfigError(
                    f"model '{sur.name}' ({sur.model_cfg.cell}) cannot be stepped statefully; use mode='windowed'"
                )
            self.fused = FusedStep(sur).to(self.device)
            self.kernel = RecurrentKernel(self.fused, n_envs=self.n_envs, impl=impl, name=sur.name)
            self.impl: str = self.kernel.impl
            shape = self.kernel.state_shape(self.n_envs)
            self.h = torch.zeros(shape, device=self.device)
            self.c = torch.zeros(shape, device=self.device)
        else:
            self.impl = "window"
            w = self.window
            self._ring = torch.zeros(self.n_envs, 2 * w, self.norm.n_feature, device=self.device)
            self._pos = 0
        self.unc: StepUncertainty | None = None
        """With ``uncertainty``: the members' spread and the OOD flags of the last step."""
        if uncertainty:
            self.unc = StepUncertainty(
                self.sur,
                n_envs=self.n_envs,
                additive=bool(sur.model_cfg.residual or sur.model_cfg.prior),
            )

    def _play_step(
        self, z: torch.Tensor, u: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Command states (play operators, delay line) after ``u`` and their raw features
        (None without any)."""
        if not self.norm.n_state:
            return z, None
        return play_and_features(self.norm, z, u)

    def dense_state(self, row: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(h, c)`` as (n_layer, n_envs, hidden) whatever the kernel's layout (``row``:
        only that env, (n_layer, 1, hidden)); copies."""
        return self.kernel.dense(self.h, self.c, row)

    def _reset(self, theta0: np.ndarray, mask: np.ndarray | None) -> None:
        theta0 = torch.as_tensor(np.asarray(theta0, dtype=np.float64), device=self.device)
        if mask is None:
            idx = torch.arange(self.n_envs, device=self.device)
        else:
            idx = torch.as_tensor(np.flatnonzero(mask), device=self.device)
            if idx.numel() == 0:
                return
        if self.unc is not None:
            self.unc.reset(idx)
        th = theta0.index_select(0, idx)
        self.theta.index_copy_(0, idx, th)
        m = idx.numel()
        w0 = None
        self.theta_prev.index_copy_(0, idx, th)
        if self.omega_in:
            self.w.index_fill_(0, idx, 0.0)  # at rest
            w0 = th.new_zeros(m, th.shape[1]).float()
        u0 = torch.as_tensor(self.u_rest, device=self.device).expand(m, -1).float()
        n_warm = self.window - 1
        z0, p0 = self._play_step(self.z.new_zeros(m, *self.z.shape[1:]), u0)
        q = self.norm.n_play
        if self.norm.n_line:  # at rest: the delay line holds the rest command throughout
            z0[:, q : self.norm.n_command] = z0[:, self.norm.n_command - 1 : self.norm.n_command]
        z0 = own_start(self.norm, z0, th.float())  # the network's own angles: the reset's
        self.z.index_copy_(0, idx, z0)  # at rest: one step reaches the play operators' fixed point
        if self.mode == "stateful":
            h = torch.zeros(self.kernel.state_shape(m), device=self.device)
            c = torch.zeros_like(h)
            if n_warm > 0:
                r = self.fused.features(th.float(), u0, p0, w0)
                _, h, c = self.kernel.seq(r.unsqueeze(1).expand(m, n_warm, -1), h, c)
            env_dim = h.dim() - 2  # (n_layer, [M,] n_envs, width)
            self.h.index_copy_(env_dim, idx, h)
            self.c.index_copy_(env_dim, idx, c)
        else:
            row = self.norm.encode(th.float(), u0, z0, w0)  # (m, n_feature)
            self._ring.index_copy_(
                0, idx, row.unsqueeze(1).expand(m, self._ring.shape[1], -1).contiguous()
            )

    # ---- public API -----------------------------------------------------------------------------

    @torch.inference_mode()
    def reset(self, theta0: np.ndarray, mask: np.ndarray | None = None) -> torch.Tensor:
        """Put the envs in ``mask`` at rest at ``theta0`` and warm the model up.

        Args:
            theta0: (n_envs, n_joint) angles [rad]; only rows in ``mask`` are used.
            mask: (n_envs,) bool; None resets every env.

        Returns:
            The current angles ``theta`` (n_envs, n_joint) float64 [rad] (a live tensor).
        """
        with self._threads:
            self._reset(theta0, mask)
        return self.theta

    @torch.inference_mode()
    def reset_history(
        self,
        theta_hist: np.ndarray,
        u_hist: np.ndarray,
        mask: np.ndarray | None = None,
    ) -> torch.Tensor:
        """Warm the envs in ``mask`` up on recorded samples instead of at rest.

        Args:
            theta_hist: (n_envs, n_hist, n_joint) angles ``theta[0..n_hist-1]`` [rad],
                ``n_hist >= 2``; only rows in ``mask`` are used.
            u_hist: (n_envs, n_hist - 1, n_u) commands ``u[0..n_hist-2]`` [command units].
            mask: (n_envs,) bool; None resets every env.

        The state is the one :class:`~excavator_surrogate.surrogate.rollout.ClosedLoop`
        reaches with ``reset(theta_hist, u_hist)`` (the free run of ``exsur evaluate`` with
        ``warmup = n_hist``; a stateful engine runs that warm-up through its own kernels):
        stepping the recorded commands from here continues that free run.  A windowed model uses the last ``W - 1`` samples; a shorter history is padded
        with its first sample.  The angle starts at ``theta[n_hist-1]``; the velocity feature
        and the OOD flags' ω[k] (:attr:`unc`) at the last backward difference, the velocity
        the observation shows.

        Returns:
            The current angles ``theta`` (n_envs, n_joint) float64 [rad] (a live tensor).
        """
        th_all = np.asarray(theta_hist, dtype=np.float64)
        u_all = np.asarray(u_hist, dtype=np.float64)
        n, n_hist = self.n_envs, th_all.shape[1] if th_all.ndim == 3 else 0
        want = ((n, n_hist, self.spec.n_joint), (n, n_hist - 1, self.spec.n_u))
        if n_hist < 2 or (th_all.shape, u_all.shape) != want:
            raise ConfigError(
                f"reset_history: need theta_hist (n_envs={n}, n_hist>=2, {self.spec.n_joint}) "
                f"and u_hist (n_envs, n_hist-1, {self.spec.n_u}), got {th_all.shape} and "
                f"{u_all.shape}"
            )
        idx_np = np.arange(n) if mask is None else np.flatnonzero(mask)
        if idx_np.size == 0:
            return self.theta
        with self._threads:
            self._reset_history(th_all[idx_np], u_all[idx_np], idx_np)
        return self.theta

    def _reset_history(self, th_hist: np.ndarray, u_hist: np.ndarray, idx_np: np.ndarray) -> None:
        dev = self.device
        idx = torch.as_tensor(idx_np, device=dev)
        th64 = torch.as_tensor(th_hist, device=dev)
        self.theta.index_copy_(0, idx, th64[:, -1])
        self.theta_prev.index_copy_(0, idx, th64[:, -2])
        # w = wrap(theta[n_hist-1] - theta[n_hist-2]) / T_s, in float64 as observe() does
        w_meas = self.norm.velocity(th64[:, -1], th64[:, -2], self.dt)
        if self.omega_in:
            self.w.index_copy_(0, idx, w_meas)
        if self.unc is not None:  # the OOD box checks the sample's measured velocity too
            self.unc.reset(idx)
            self.unc.omega.index_copy_(0, idx, w_meas)
        if self.mode == "stateful":
            z, h, c = self._warm_stateful(th64.float(), torch.as_tensor(u_hist, device=dev).float())
            env_dim = h.dim() - 2  # (n_layer, [M,] m, width)
            self.h.index_copy_(env_dim, idx, h)
            self.c.index_copy_(env_dim, idx, c)
            self.z.index_copy_(0, idx, z)
            return
        # windowed: the reference path's own rows (no network call), into the ring
        loop = ClosedLoop(self.sur, mode=self.mode)
        loop.reset(th_hist, u_hist)
        assert loop.z is not None and loop.window_rows is not None
        self.z.index_copy_(0, idx, loop.z.to(self.z.dtype))
        rows = loop.window_rows.to(self._ring.dtype)  # (m, <= W-1, n_feature), oldest first
        m, w1 = idx.numel(), self.window - 1
        if rows.shape[1] < w1:  # a short history: repeat its first sample, as ClosedLoop
            pad = rows[:, :1].expand(m, w1 - rows.shape[1], rows.shape[2])
            rows = torch.cat([pad, rows], dim=1)
        # step() writes the next row at _pos and reads ring[_pos + 1 : _pos + W + 1]:
        # the W - 1 rows before it sit at (_pos + 1 + j) mod W, twice (the doubled ring)
        w = self.window
        slots = [(self._pos + 1 + j) % w for j in range(w1)]
        for j, q in enumerate(slots):
            self._ring[idx, q] = rows[:, j]
            self._ring[idx, q + w] = rows[:, j]

    def _warm_stateful(
        self, theta: torch.Tensor, u: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``ClosedLoop.reset``'s warm-up through this engine's own kernels: the command
        states from rest before ``u[0]``, every recorded sample's raw features (the recorded
        angle on every joint, the measured velocity feature), one sequence call.

        Args:
            theta: (m, n_hist, n_joint) float32 [rad]; u: (m, n_hist - 1, n_u) float32.

        Returns:
            ``z`` (m, Q + L [+ 2], n_joint) after ``u[n_hist-2]`` (the network's own angle and
            velocity: the last recorded), and ``h``, ``c`` in the kernel's layout.
        """
        m, n_hist, _ = theta.shape
        w_hist = self.norm.velocity_seq(theta, self.dt) if self.omega_in else None
        z = self.z.new_zeros(m, *self.z.shape[1:])  # at rest before u[0]
        rows = []
        for k in range(n_hist - 1):
            z, p = self._play_step(z, u[:, k])
            w_k = None if w_hist is None else w_hist[:, k]
            rows.append(self.fused.features(theta[:, k], u[:, k], p, w_k))
        h = torch.zeros(self.kernel.state_shape(m), device=self.device)
        c = torch.zeros_like(h)
        _, h, c = self.kernel.seq(torch.stack(rows, dim=1), h, c)
        z = own_start(self.norm, z, theta[:, -1], None if w_hist is None else w_hist[:, -1])
        return z, h, c

    @torch.inference_mode()
    def observe(self, theta: np.ndarray | torch.Tensor) -> None:
        """Overwrite the current angles with measured ones ``theta`` (n_envs, n_joint) [rad]:
        the next :meth:`step` then consumes the measurement (teacher forcing), which keeps the
        recurrent state synced to a real machine's measured history.  The velocity feature
        (with one) and the OOD flags' ω[k] (:attr:`unc`) become the measured
        ``wrap(theta - theta_prev) / T_s``, from the angle the last step started from (the
        reset angle if none)."""
        self.theta.copy_(torch.as_tensor(np.asarray(theta, dtype=np.float64), device=self.device))
        w_meas = self.norm.velocity(self.theta, self.theta_prev, self.dt)
        if self.omega_in:
            self.w.copy_(w_meas)
        if self.unc is not None:
            self.unc.omega.copy_(w_meas)
        # joints on a map in parallel: the network reads the measurement too
        self.z = own_start(self.norm, self.z, self.theta, self.w if self.omega_in else None)

    @torch.inference_mode()
    def export_row(self, row: int = 0) -> dict[str, torch.Tensor | int]:
        """The complete state of env ``row`` in a kernel-independent layout (copies): ``theta``,
        ``theta_prev``, ``w`` (1, n_joint), ``z`` (1, Q, n_joint) and ``h``, ``c`` (n_layer, 1,
        hidden) (stateful) or ``ring`` (1, 2 W, n_feature) and ``pos`` (windowed).  :meth:`fork_state` continues
        it, here or in another process's engine of the same surrogate."""
        out: dict[str, torch.Tensor | int] = {
            "theta": self.theta[row : row + 1].clone(),
            "theta_prev": self.theta_prev[row : row + 1].clone(),
            "w": self.w[row : row + 1].clone(),
            "z": self.z[row : row + 1].clone(),
        }
        if self.mode == "stateful":
            out["h"], out["c"] = self.dense_state(row)
        else:
            out["ring"], out["pos"] = self._ring[row : row + 1].clone(), self._pos
        return out

    @torch.inference_mode()
    def fork_state(self, state: dict[str, torch.Tensor | int]) -> torch.Tensor:
        """Put every env in the state ``state`` of :meth:`export_row` (same surrogate and mode).

        Returns:
            The current angles ``theta`` (n_envs, n_joint) float64 [rad] (a live tensor).
        """
        if ("h" in state) != (self.mode == "stateful"):
            raise ConfigError("fork: both engines must run the same surrogate in the same mode")
        dev = self.device
        if self.unc is not None:  # the spread restarts from the forked state (no deviation)
            self.unc.reset(torch.arange(self.n_envs, device=dev))
        self.theta.copy_(torch.as_tensor(state["theta"], device=dev).expand_as(self.theta))
        self.z = torch.as_tensor(state["z"], device=dev).expand_as(self.z).clone()
        for k in ("theta_prev", "w"):
            getattr(self, k).copy_(torch.as_tensor(state[k], device=dev).expand_as(self.theta))
        if self.mode == "stateful":
            # (n_layer, 1, hidden) -> the kernel's layout
            h, c = self.kernel.from_dense(
                torch.as_tensor(state["h"], device=dev), torch.as_tensor(state["c"], device=dev)
            )
            self.h = h.expand_as(self.h).contiguous()
            self.c = c.expand_as(self.c).contiguous()
        else:
            ring = torch.as_tensor(state["ring"], device=dev)
            self._ring = ring.expand_as(self._ring).contiguous()
            self._pos = int(state["pos"])
        return self.theta

    @torch.inference_mode()
    def fork(self, src: SurrogateEngine, row: int = 0) -> torch.Tensor:
        """Copy env ``row`` of ``src`` (same surrogate and mode) into every env of this engine.

        Afterwards each of the ``n_envs`` copies continues exactly as ``src``'s env ``row``
        would (a sampling planner's candidates start from the synced machine state).

        Returns:
            The current angles ``theta`` (n_envs, n_joint) float64 [rad] (a live tensor).
        """
        if src.mode != self.mode or src.window != self.window or src.spec != self.spec:
            raise ConfigError("fork: both engines must run the same surrogate in the same mode")
        return self.fork_state(src.export_row(row))

    @torch.inference_mode()
    def step(self, u: np.ndarray | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Apply commands ``u`` (n_envs, n_u) [command units] at the current sample k (the
        joints', then the exogenous inputs').

        Returns ``(theta[k+1], omega[k+1])`` as (n_envs, n_joint) float64 tensors [rad], [rad/s]
        (``theta`` is the engine's live state tensor: copy it to keep it).
        """
        with self._threads:
            u_t = torch.as_tensor(u, device=self.device).float()
            theta = self.theta
            w_t = self.w.float() if self.omega_in else None
            self.theta_prev.copy_(theta)
            self.z, p_t = self._play_step(self.z, u_t)
            unc, om_m = self.unc, None
            if unc is not None:
                unc.flag(theta, u_t)
            # the angles and velocity the network reads (its own on joints on a map in parallel)
            th_in, w_in = network_inputs(self.norm, theta.float(), self.z, w_t)
            if self.mode == "stateful":
                f = self.fused
                r = f.features(th_in, u_t, p_t, w_in)
                a, self.h, self.c = self.kernel.step(r, self.h, self.c)
                _, _, w2, b2 = self.kernel.head
                omega = torch.addmm(b2, a, w2.t())
                # omega[k] (residual) or s(u[k - d]) (prior), else None
                base = f.base(u_t, w_in, self.z)
                if unc is not None and unc.n_member:  # the same call's activations, per member
                    om_m = unc.members_from_activations(a, base)
                if base is not None:
                    omega = omega + base  # omega[k+1] = base + change
                omega = omega.double()
            else:
                w, p = self.window, self._pos
                row = self.norm.encode(th_in, u_t, self.z, w_in)
                self._ring[:, p] = row
                self._ring[:, p + w] = row
                if unc is not None and unc.head is not None:
                    with unc.head.capture():
                        y = self.sur.net(self._ring[:, p + 1 : p + w + 1])
                    om_m = self.norm.omega(unc.head.outputs(row))
                else:
                    y = self.sur.net(self._ring[:, p + 1 : p + w + 1])
                self._pos = (p + 1) % w
                omega = self.norm.omega(y).double()
            if self._own_dev is not None:  # map joints in parallel: the map's speed; own angles on
                omega, self.z = own_advance(
                    self.norm, self.z, u_t, omega, dt=self.dt, limits=self._limits
                )
                if om_m is not None:  # member m drives a map joint with gain 1 + dev[m]
                    om_m = own_members(self.norm, om_m, omega, self._own_dev)
            if self._limits is None:
                theta.add_(omega, alpha=self.dt)
            else:
                theta_next, omega = integrate(theta, omega, dt=self.dt, limits=self._limits)
                theta.copy_(theta_next)
            if self.omega_in:
                self.w.copy_(omega)
            if unc is not None:
                unc.advance(om_m, omega, theta=theta, limits=self._limits)
        return theta, omega
