"""Batched, allocation-light closed-loop engine behind the surrogate environments.

:class:`FusedStep` is the single-step surrogate with the feature encoding and the feature /
target normalisation *folded into the weights*: it maps raw angles and commands straight to
angular velocities, ``(theta, u, h, c) -> (omega, theta_next, h', c')``.  It is written with
plain matmuls and pointwise ops, so it exports to ONNX as is (see :mod:`.export`).

:class:`SurrogateEngine` steps ``n_envs`` copies of a surrogate in one torch batch:

- **stateful** checkpoints (``mode="stateful"``) are stepped one sample at a time carrying
  ``(h, c)``; small batches use ``torch.lstm_cell``/``torch.gru_cell`` per layer, large ones a
  folded ``nn.LSTM``/``nn.GRU`` (oneDNN), both with the folded weights; a merged LSTM seed
  ensemble steps its members' diagonal blocks as one batched matmul from 64 envs on
  (:mod:`.members`), skipping the zero blocks of the dense kernels;
- **windowed** checkpoints re-run their ``W``-sample window every step from a zero state, as
  they were trained, from a rolling buffer (a doubled ring buffer: no copies per step).

Warm-up after a reset is "at rest": ``W - 1`` samples with the angle held at ``theta0`` and
``u = 0`` (clipped into the command range), exactly what
:class:`~excavator_surrogate.surrogate.rollout.ClosedLoop` does with a constant history.
Resets are masked: only the envs in ``mask`` get new angles and a fresh warm-up state.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import torch
from torch import nn

from ..devices import resolve_device
from ..errors import ConfigError
from ..spec import MachineSpec
from ..surrogate.ensemble import n_member
from ..surrogate.features import Normalization, integrate, play_features, play_step
from ..surrogate.model import Surrogate, step_layers
from .inputs import ActionLayout
from .members import MemberLSTM, from_dense, to_dense

Mode = Literal["windowed", "stateful"]
Impl = Literal["auto", "cell", "module", "members"]

MODULE_MIN_BATCH = 256
"""``impl="auto"`` uses the folded ``nn.LSTM`` module (oneDNN) from this batch size on."""

MEMBERS_MIN_BATCH = 64
"""``impl="auto"`` steps a merged LSTM ensemble member by member from this batch size on
(measured on one core, two members of width 64: 0.94x the dense cell at 64 envs with the
slice-and-concatenate prototype, 0.66x at 256)."""

SINGLE_THREAD_MAX_BATCH = 128
"""Below this batch size a step runs with ONE torch thread (restored afterwards): tiny matmuls
do not gain from threads, and on a shared machine OpenMP barriers waiting for descheduled
threads made small-batch steps up to 10x slower."""


class _OneThread:
    """Context manager: ``torch.set_num_threads(1)`` inside, previous count restored after."""

    __slots__ = ("prev",)

    def __init__(self) -> None:
        self.prev = 1

    def __enter__(self) -> None:
        self.prev = torch.get_num_threads()
        if self.prev != 1:
            torch.set_num_threads(1)

    def __exit__(self, *exc: object) -> None:
        if self.prev != 1:
            torch.set_num_threads(self.prev)


class _NoOp:
    __slots__ = ()

    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def rest_command(spec: MachineSpec) -> np.ndarray:
    """The at-rest command (n_u,): 0 clipped into each joint's ``[u_min, u_max]``, then each
    exogenous input at the centre of its range (an env with fixed inputs overrides them)."""
    return ActionLayout(spec).rest()


def _fold_input(sur: Surrogate) -> tuple[np.ndarray, np.ndarray]:
    """Matrix ``M`` (n_feature, n_raw) and offset ``e`` (n_feature,) with
    ``x_norm = M @ r + e`` for raw features ``r = [theta (J), sin θ_p, cos θ_p, u (n_u), f]``
    (``u``: the joints' commands then the exogenous inputs; ``f``: the Q * J play features
    ``(z - us) / b``, if any)."""
    spec, norm = sur.spec, sur.norm
    n_joint, n_u = spec.n_joint, spec.n_u
    per = [k for k, p in enumerate(spec.periodic) if p]
    n_per = len(per)
    n_play = norm.n_play * n_joint
    n_raw = n_joint + 2 * n_per + n_u + n_play
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
    for k in range(n_play):
        mat[col, n_joint + 2 * n_per + n_u + k] = 1.0 / s[col]
        col += 1
    return mat, off


def add_play(module: nn.Module, sur: Surrogate) -> None:
    """Register the surrogate's play operators on ``module``: float32 buffers ``play`` (Q,)
    half-widths, ``u_center`` / ``u_scale`` (n_u,); ``module.n_play`` = Q (0: none)."""
    norm = sur.norm.to("cpu", torch.float32)
    module.n_play = norm.n_play
    for k in ("play", "u_center", "u_scale"):
        module.register_buffer(k, getattr(norm, k).clone())


def play_and_features(
    module: nn.Module | Normalization, z: torch.Tensor, u: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Play states after ``u`` and their features, with the buffers of :func:`add_play` (or
    the same-named tensors of a :class:`Normalization`).

    Args:
        z: (..., Q, n_joint) play states before ``u``.
        u: (..., n_u) commands [command units]; the first ``n_joint`` (the joints') drive
            the play operators, exogenous inputs do not.

    Returns:
        ``z_new`` (..., Q, n_joint) and features ``(z_new - us) / b`` (..., Q * n_joint).
    """
    nj = z.shape[-1]
    us = (u[..., :nj] - module.u_center[:nj]) / module.u_scale[:nj]
    z = play_step(z, us, module.play)
    return z, play_features(z, us, module.play)


def add_end_stops(module: nn.Module, sur: Surrogate) -> None:
    """Register the surrogate's envelope on ``module`` as float32 buffers ``theta_lo`` /
    ``theta_hi`` (n_joint,) [rad] and ``omega_max`` (n_joint,) [rad/s], each None when the
    surrogate has none (they then stay out of the graph)."""
    lim = sur.limits_np()
    for name, k in (("theta_lo", 0), ("theta_hi", 1), ("omega_max", 2)):
        has = lim is not None and k < len(lim)
        module.register_buffer(name, torch.tensor(lim[k], dtype=torch.float32) if has else None)


def end_stops(module: nn.Module) -> tuple[torch.Tensor, ...] | None:
    """The ``(theta_lo, theta_hi[, omega_max])`` buffers of :func:`add_end_stops`, or None."""
    lo, hi, w = module.theta_lo, module.theta_hi, module.omega_max
    if lo is None:
        return None
    return (lo, hi) if w is None else (lo, hi, w)  # type: ignore[return-value]


class FusedStep(nn.Module):
    """One closed-loop step with encoding and normalisation folded into the weights.

    ``forward(theta, u, h, c[, z])``:

    - ``theta``: (n_batch, n_joint) angles θ[k] [rad] (periodic joints wrapped or not);
    - ``u``: (n_batch, n_u) commands u[k] [command units] (joints', then exogenous inputs');
    - ``h``, ``c``: (n_layer, n_batch, hidden) recurrent state (``c`` unused and passed
      through for GRU cells);
    - ``z``: (n_batch, Q, n_joint) play states before ``u`` (only if the surrogate has
      ``Q = n_play > 0`` play features).

    Returns ``omega`` (n_batch, n_joint) = ω̂[k+1] [rad/s], ``theta_next`` = θ + T_s·ω̂
    [rad] (clipped to the end stops if the surrogate has them), the new ``h``, ``c`` and,
    with play features, the new ``z``.  Only LSTM/GRU surrogates can be fused.
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
        self.hidden = sur.model_cfg.hidden
        self.n_joint = spec.n_joint
        self.dt = float(spec.dt)
        per = [k for k, p in enumerate(spec.periodic) if p]
        self.register_buffer("periodic_idx", torch.tensor(per, dtype=torch.long), persistent=False)
        self.has_periodic = bool(per)
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
        b2 = lin2.bias.detach().double().cpu().numpy() * y_std + y_mean
        self.w1 = nn.Parameter(lin1.weight.detach().float().clone(), requires_grad=False)
        self.b1 = nn.Parameter(lin1.bias.detach().float().clone(), requires_grad=False)
        self.w2 = nn.Parameter(torch.tensor(w2, dtype=f32), requires_grad=False)
        self.b2 = nn.Parameter(torch.tensor(b2, dtype=f32), requires_grad=False)

    @property
    def n_raw(self) -> int:
        """Width of the raw feature vector ``[theta, sin θ_p, cos θ_p, u]``."""
        return int(self.w_ih[0].shape[1])

    def features(
        self, theta: torch.Tensor, u: torch.Tensor, f: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Raw features ``[theta, sin θ_p, cos θ_p, u, f]`` (n_batch, n_raw), float32, with
        ``f`` the play features of :func:`play_and_features` (None without play)."""
        tail = [u] if f is None else [u, f]
        if self.has_periodic:
            tp = theta.index_select(-1, self.periodic_idx)
            return torch.cat([theta, torch.sin(tp), torch.cos(tp), *tail], dim=-1)
        return torch.cat([theta, *tail], dim=-1)

    def head(self, out: torch.Tensor) -> torch.Tensor:
        """Angular velocity [rad/s] from the last layer's output (n_batch, hidden)."""
        z = torch.relu(torch.nn.functional.linear(out, self.w1, self.b1))
        return torch.nn.functional.linear(z, self.w2, self.b2)

    def forward(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        z: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, ...]:
        """See the class docstring."""
        f = None
        if self.n_play:
            if z is None:
                raise ValueError("this surrogate has play features: pass the play state z")
            z, f = play_and_features(self, z, u)
        inp = self.features(theta, u, f)
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
        theta_next, omega = integrate(theta, self.head(inp), dt=self.dt, limits=end_stops(self))
        if self.n_play:
            return omega, theta_next, torch.stack(hs), torch.stack(cs), z
        return omega, theta_next, torch.stack(hs), torch.stack(cs)


class SurrogateEngine:
    """``n_envs`` surrogate copies stepped in one torch batch, with masked resets.

    Args:
        sur: the loaded surrogate (:func:`~excavator_surrogate.surrogate.checkpoint.load_checkpoint`).
        n_envs: batch size.
        device: torch device for the state and the network (``cpu``, ``cuda[:N]``, ``auto``).
        mode: ``"stateful"`` or ``"windowed"``; default: the checkpoint's training mode.
        impl: stateful implementation: ``"cell"`` (per-layer cell ops), ``"module"`` (folded
            ``nn.LSTM``), ``"members"`` (a merged LSTM ensemble's members as one batched
            matmul, :mod:`.members`) or ``"auto"`` (members from :data:`MEMBERS_MIN_BATCH`
            envs on when the surrogate is such an ensemble, else module from
            :data:`MODULE_MIN_BATCH` envs on, else cell).

    State: ``theta`` (n_envs, n_joint) float64 [rad]; ``h``, ``c`` (n_layer, n_envs, hidden)
    (stateful; ``impl="members"``: (n_layer, M, n_envs, hidden / M), see
    :meth:`dense_state`) or a ring buffer of normalised features (windowed); ``z`` (n_envs,
    Q, n_joint) play states of the commands (Q = 0 unless the surrogate has play features).
    """

    def __init__(
        self,
        sur: Surrogate,
        *,
        n_envs: int,
        device: str | torch.device = "cpu",
        mode: Mode | None = None,
        impl: Impl = "auto",
    ) -> None:
        if n_envs < 1:
            raise ConfigError(f"n_envs must be >= 1, got {n_envs}")
        self.mode: Mode = mode or sur.mode
        if self.mode not in ("windowed", "stateful"):
            raise ConfigError(f"mode must be 'windowed' or 'stateful', got {self.mode!r}")
        if impl not in ("auto", "cell", "module", "members"):
            raise ConfigError(f"impl must be 'auto', 'cell', 'module' or 'members', got {impl!r}")
        self.device = resolve_device(device)
        self.sur = sur.to(self.device, torch.float32).eval()
        self.spec = sur.spec
        self.n_envs = int(n_envs)
        self.window = int(sur.window)
        self.dt = float(self.spec.dt)
        self.u_rest = rest_command(self.spec)
        self._threads = _OneThread() if self.n_envs < SINGLE_THREAD_MAX_BATCH else _NoOp()
        n_joint = self.spec.n_joint
        self.theta = torch.zeros(self.n_envs, n_joint, dtype=torch.float64, device=self.device)
        self.norm = sur.norm.to(self.device, torch.float32)
        self.z = torch.zeros(self.n_envs, self.norm.n_play, n_joint, device=self.device)
        lim = sur.limits()
        self._limits = None if lim is None else tuple(a.double() for a in lim)
        self._members: MemberLSTM | None = None
        if self.mode == "stateful":
            if sur.model_cfg.cell not in ("lstm", "gru"):
                raise ConfigError(
                    f"model '{sur.name}' ({sur.model_cfg.cell}) cannot be stepped statefully; use mode='windowed'"
                )
            self.fused = f = FusedStep(sur).to(self.device)
            # plain tensors: indexing ParameterLists costs more than the cell ops at n_envs = 1
            self._layers = [
                (f.w_ih[k].data, f.w_hh[k].data, f.b_ih[k].data, f.b_hh[k].data)
                for k in range(f.n_layer)
            ]
            self._head = (f.w1.data, f.b1.data, f.w2.data, f.b2.data)
            self._is_lstm = f.cell == "lstm"
            self._members = self._member_kernel(sur, impl)
            if self._members is not None:
                self.impl = "members"
            elif impl == "auto":
                self.impl = "module" if self.n_envs >= MODULE_MIN_BATCH else "cell"
            else:
                self.impl = impl
            shape = self._state_shape(self.n_envs)
            self.h = torch.zeros(shape, device=self.device)
            self.c = torch.zeros(shape, device=self.device)
            self._module = self._folded_module() if self.impl == "module" else None
        else:
            self.impl = "window"
            w = self.window
            self._ring = torch.zeros(self.n_envs, 2 * w, self.norm.n_feature, device=self.device)
            self._pos = 0

    def _play_step(
        self, z: torch.Tensor, u: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Play states after ``u`` and their raw features (None without play features)."""
        if not self.norm.n_play:
            return z, None
        return play_and_features(self.norm, z, u)

    # ---- stateful internals -------------------------------------------------------------------

    def _member_kernel(self, sur: Surrogate, impl: Impl) -> MemberLSTM | None:
        """The per-member kernel when ``impl`` asks for it (or ``auto`` picks it), else None."""
        if impl not in ("auto", "members"):
            return None
        kernel = MemberLSTM.from_layers(self._layers, n_member(sur)) if self._is_lstm else None
        if impl == "members" and kernel is None:
            raise ConfigError(
                f"impl='members' needs a merged LSTM seed ensemble of equal members; "
                f"'{sur.name}' is not one (use impl='auto')"
            )
        if impl == "auto" and self.n_envs < MEMBERS_MIN_BATCH:
            return None
        return kernel

    def _state_shape(self, n: int) -> tuple[int, ...]:
        """Shape of ``h``/``c`` for ``n`` envs in this engine's layout."""
        f = self.fused
        if self._members is not None:
            m = self._members
            return (f.n_layer, m.n_member, n, m.width)
        return (f.n_layer, n, f.hidden)

    def dense_state(self, row: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(h, c)`` as (n_layer, n_envs, hidden) whatever the kernel's layout (``row``:
        only that env, (n_layer, 1, hidden)); copies."""
        sl = slice(None) if row is None else slice(row, row + 1)
        if self._members is not None:
            return to_dense(self.h[:, :, sl]), to_dense(self.c[:, :, sl])
        return self.h[:, sl].clone(), self.c[:, sl].clone()

    def _folded_module(self) -> nn.Module:
        f = self.fused
        cls = nn.LSTM if f.cell == "lstm" else nn.GRU
        mod = cls(f.n_raw, f.hidden, num_layers=f.n_layer, batch_first=True).to(self.device)
        with torch.no_grad():
            for layer in range(f.n_layer):
                getattr(mod, f"weight_ih_l{layer}").copy_(f.w_ih[layer])
                getattr(mod, f"weight_hh_l{layer}").copy_(f.w_hh[layer])
                getattr(mod, f"bias_ih_l{layer}").copy_(f.b_ih[layer])
                getattr(mod, f"bias_hh_l{layer}").copy_(f.b_hh[layer])
        mod.requires_grad_(False)
        return mod.eval()

    def _rnn_cells(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One sample through the layers with cell ops; x (m, n_raw); returns (out, h, c) new tensors."""
        return step_layers(x, h, c, self._layers, lstm=self._is_lstm)

    def _rnn_seq(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A sequence x (m, n_step, n_raw) from state (h, c); returns (last output, h, c)."""
        if self._members is not None:
            out = x.new_zeros(x.shape[0], self.fused.hidden)
            for k in range(x.shape[1]):
                out, h, c = self._members.step(x[:, k], h, c)
            return out, h, c
        if self.impl == "module":
            assert self._module is not None
            if self.fused.cell == "lstm":
                out, (h, c) = self._module(x, (h.contiguous(), c.contiguous()))
            else:
                out, h = self._module(x, h.contiguous())
            return out[:, -1], h, c
        out = x.new_zeros(x.shape[0], self.fused.hidden)
        for k in range(x.shape[1]):
            out, h, c = self._rnn_cells(x[:, k], h, c)
        return out, h, c

    def _reset(self, theta0: np.ndarray, mask: np.ndarray | None) -> None:
        theta0 = torch.as_tensor(np.asarray(theta0, dtype=np.float64), device=self.device)
        if mask is None:
            idx = torch.arange(self.n_envs, device=self.device)
        else:
            idx = torch.as_tensor(np.flatnonzero(mask), device=self.device)
            if idx.numel() == 0:
                return
        th = theta0.index_select(0, idx)
        self.theta.index_copy_(0, idx, th)
        m = idx.numel()
        u0 = torch.as_tensor(self.u_rest, device=self.device).expand(m, -1).float()
        n_warm = self.window - 1
        z0, p0 = self._play_step(self.z.new_zeros(m, *self.z.shape[1:]), u0)
        self.z.index_copy_(0, idx, z0)  # at rest: one step reaches the play operators' fixed point
        if self.mode == "stateful":
            f = self.fused
            h = torch.zeros(self._state_shape(m), device=self.device)
            c = torch.zeros_like(h)
            if n_warm > 0:
                r = f.features(th.float(), u0, p0)
                _, h, c = self._rnn_seq(r.unsqueeze(1).expand(m, n_warm, -1), h, c)
            env_dim = h.dim() - 2  # (n_layer, [M,] n_envs, width)
            self.h.index_copy_(env_dim, idx, h)
            self.c.index_copy_(env_dim, idx, c)
        else:
            row = self.norm.encode(th.float(), u0, z0)  # (m, n_feature)
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
    def observe(self, theta: np.ndarray | torch.Tensor) -> None:
        """Overwrite the current angles with measured ones ``theta`` (n_envs, n_joint) [rad]:
        the next :meth:`step` then consumes the measurement (teacher forcing), which keeps the
        recurrent state synced to a real machine's measured history."""
        self.theta.copy_(torch.as_tensor(np.asarray(theta, dtype=np.float64), device=self.device))

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
        self.theta.copy_(src.theta[row].expand_as(self.theta))
        self.z = src.z[row : row + 1].expand_as(self.z).clone()
        if self.mode == "stateful":
            h, c = src.dense_state(row)  # (n_layer, 1, hidden): the kernels' layouts may differ
            if self._members is not None:
                h, c = from_dense(h, self._members.n_member), from_dense(c, self._members.n_member)
            self.h = h.expand_as(self.h).contiguous()
            self.c = c.expand_as(self.c).contiguous()
        else:
            self._ring = src._ring[row : row + 1].expand_as(self._ring).contiguous()
            self._pos = src._pos
        return self.theta

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
            self.z, p_t = self._play_step(self.z, u_t)
            if self.mode == "stateful":
                f = self.fused
                r = f.features(theta.float(), u_t, p_t)
                if self._members is not None:
                    out, self.h, self.c = self._members.step(r, self.h, self.c)
                elif self.impl == "module":
                    out, self.h, self.c = self._rnn_seq(r.unsqueeze(1), self.h, self.c)
                else:
                    out, self.h, self.c = self._rnn_cells(r, self.h, self.c)
                w1, b1, w2, b2 = self._head
                omega = torch.addmm(b2, torch.relu(torch.addmm(b1, out, w1.t())), w2.t()).double()
            else:
                w, p = self.window, self._pos
                row = self.norm.encode(theta.float(), u_t, self.z)
                self._ring[:, p] = row
                self._ring[:, p + w] = row
                y = self.sur.net(self._ring[:, p + 1 : p + w + 1])
                self._pos = (p + 1) % w
                omega = self.norm.omega(y).double()
            if self._limits is None:
                theta.add_(omega, alpha=self.dt)
            else:
                theta_next, omega = integrate(theta, omega, dt=self.dt, limits=self._limits)
                theta.copy_(theta_next)
        return theta, omega


def wrap_periodic(theta: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """Copy of ``theta`` (..., n_joint) with periodic joints wrapped to ``[-π, π)`` [rad]."""
    out = np.array(theta, dtype=np.float64, copy=True)
    if periodic.any():
        out[..., periodic] = (out[..., periodic] + math.pi) % (2.0 * math.pi) - math.pi
    return out
