"""Free-run training chunks with a hand-written backward pass (the fast path of ``Stateful``).

In free-run training (:class:`~.modes.Stateful` with ``feedback = "free"``) each TBPTT chunk
of ``n_step`` samples runs, per sample ``k``:

    x[k]       = (raw(theta[k], u[k], z[k], omega[k]) - x_mean) / x_std      (encode)
    h, c, y[k] = cells(x[k], h, c), head                                      (net.step)
    omega_hat  = y[k] * y_std + y_mean
    theta[k+1], omega[k+1] = integrate(theta[k], omega_hat)                  (end stops)

Through autograd that is ~60 small operator nodes per sample, each a few microseconds of
dispatch and bookkeeping for a 64 x 64 GEMM's worth of arithmetic; the network's weight
gradients are accumulated sample by sample.  :func:`free_run_chunk` runs the same forward
maths under ``no_grad`` (the same ATen operators in the same order, so ``y_hat`` has the
reference's values) and one :class:`torch.autograd.Function` back-propagates the whole chunk
by hand: through time, through the integration and the angle features, with each weight's
gradient summed over the chunk by one GEMM over all its samples.

It covers what the presets train: stacked LSTM cells, the FC-ReLU-linear head, the residual
head, the speed prior (a function of the commands only), play features and delayed commands
(functions of the commands only), exogenous inputs, periodic joints, end stops and speed
bounds.  For anything else (a GRU, another head) :func:`supported` is False and the caller
keeps the autograd path.  Tested against that path (values and gradients) in
``tests/training/test_free_run.py``.

Ties: where a clipped quantity lands exactly on its bound, autograd's ``maximum``/``minimum``
split the gradient in halves; here it passes whole.  That needs an exact float tie between
a prediction and a limit, and changes only that sample's gradient.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from ..surrogate.angles import integrate
from ..surrogate.features import Normalization
from ..surrogate.model import SurrogateNet

State = tuple[torch.Tensor, torch.Tensor]


@dataclass(frozen=True)
class _Plan:
    """What one chunk needs besides the differentiable weights."""

    net: SurrogateNet
    norm: Normalization
    dt: float
    limits: tuple[torch.Tensor, ...] | None


def supported(net: nn.Module) -> bool:
    """True when :func:`free_run_chunk` can run ``net``: a :class:`SurrogateNet` of LSTM cells
    with the FC-ReLU-linear head, in float32 or float64 on the CPU."""
    if not isinstance(net, SurrogateNet) or net.cfg.cell != "lstm" or not net._flat_layout:
        return False
    head = net.head
    return (
        len(head) == 3
        and isinstance(head[0], nn.Linear)
        and isinstance(head[1], nn.ReLU)
        and isinstance(head[2], nn.Linear)
        and net.rnn.bias
        and net.rnn.proj_size == 0
        and next(net.parameters()).device.type == "cpu"
    )


def _weights(net: SurrogateNet) -> list[torch.Tensor]:
    """The differentiable tensors: the cells' ``(w_ih, w_hh, b_ih, b_hh)`` per layer, then the
    head's ``(w1, b1, w2, b2)``."""
    return [
        *net.rnn._flat_weights,
        net.head[0].weight,
        net.head[0].bias,
        net.head[2].weight,
        net.head[2].bias,
    ]


def _commands(norm: Normalization, u: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """The normalised command columns of every sample at once (they do not depend on the
    angles): ``u: (n_batch, n_step, n_u)``, ``z: (n_batch, n_step, P + L, n_joint)`` ->
    ``(n_batch, n_step, n_u + P * n_joint [+ n_joint])``, the same values as
    :meth:`Normalization.encode`'s columns (the same element-wise operations)."""
    raw = norm.command_raw(u, z)
    lo, hi = norm.n_angle, norm.n_angle + raw.shape[-1]
    return (raw - norm.x_mean[lo:hi]) / norm.x_std[lo:hi]


@dataclass
class _Buffers:
    """A chunk's intermediate values, sample-major ``(n_step, n_batch, ...)``; ``c``, ``h``
    per layer hold the start state in row 0 and sample k's new state in row k + 1."""

    x: torch.Tensor
    theta: torch.Tensor
    y: torch.Tensor
    gates: list[torch.Tensor]
    c: list[torch.Tensor]
    h: list[torch.Tensor]
    tc: list[torch.Tensor]
    a1: torch.Tensor


class _Chunk(torch.autograd.Function):
    """``y_hat`` of a free-run chunk as a function of the network's weights (the chunk's
    start state, angles and velocities are constants: the caller detaches them).

    The forward pass writes every sample's intermediate values into per-chunk buffers
    (``(n_step, n_batch, ...)``); the backward pass derives the factors it multiplies by
    (the gates' derivatives, the clip masks) for all samples at once, then goes back through
    the samples with ~25 operators each, and sums each weight's gradient over the chunk with
    one GEMM."""

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        plan: _Plan,
        theta: torch.Tensor,
        omega: torch.Tensor,
        state: State,
        cmd: torch.Tensor,
        *weights: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        net, norm, dt, limits = plan.net, plan.norm, plan.dt, plan.limits
        n_layer, n_joint = net.cfg.n_layer, net.cfg.n_joint
        cells = [weights[4 * k : 4 * k + 4] for k in range(n_layer)]
        w1, b1, w2, b2 = weights[4 * n_layer :]
        na, omega_in = norm.n_angle, norm.omega_in
        m_a, s_a = norm.x_mean[:na], norm.x_std[:na]
        m_w, s_w = norm.x_mean[-n_joint:], norm.x_std[-n_joint:]
        residual, prior = net.cfg.residual, net.prior
        y_std, y_mean = norm.y_std, norm.y_mean
        n_step, (_, n_batch, hidden) = cmd.shape[1], state[0].shape
        new = theta.new_empty
        b = _Buffers(
            x=new(n_step, n_batch, norm.n_feature),
            theta=new(n_step, n_batch, n_joint),
            y=new(n_step, n_batch, n_joint),
            gates=[new(n_step, n_batch, 4 * hidden) for _ in range(n_layer)],
            c=[
                torch.cat([state[1][k : k + 1], new(n_step, n_batch, hidden)])
                for k in range(n_layer)
            ],
            h=[
                torch.cat([state[0][k : k + 1], new(n_step, n_batch, hidden)])
                for k in range(n_layer)
            ],
            tc=[new(n_step, n_batch, hidden) for _ in range(n_layer)],
            a1=new(n_step, n_batch, w1.shape[0]),
        )
        for k in range(n_step):
            b.theta[k] = theta
            # x[k] = (raw(theta, u, z, omega) - x_mean) / x_std, column block by column block
            xs = [(norm.angle_raw(theta) - m_a) / s_a, cmd[:, k]]
            if omega_in:
                xs.append((omega - m_w) / s_w)
            x = torch.cat(xs, dim=-1, out=b.x[k])
            inp = x
            for layer, (w_ih, w_hh, b_ih, b_hh) in enumerate(cells):
                # gates = (W_hh h + b_hh) + (W_ih x + b_ih)        (torch.lstm_cell's order)
                gates = torch.addmm(b_hh, b.h[layer][k], w_hh.t(), out=b.gates[layer][k])
                gates.add_(F.linear(inp, w_ih, b_ih))
                i, f, g, o = gates.unsafe_chunk(4, 1)
                i, f, g, o = i.sigmoid_(), f.sigmoid_(), g.tanh_(), o.sigmoid_()
                # c' = f c + i g;  h' = o tanh(c')
                c_new = torch.mul(f, b.c[layer][k], out=b.c[layer][k + 1]).add_(i * g)
                inp = torch.mul(o, torch.tanh(c_new, out=b.tc[layer][k]), out=b.h[layer][k + 1])
            # y = W2 relu(W1 h + b1) + b2 (+ the velocity feature) (+ the prior's speed)
            a1 = torch.addmm(b1, inp, w1.t(), out=b.a1[k])
            y = F.linear(F.relu(a1), w2, b2)
            if residual:
                y = y + x[..., -n_joint:]
            if prior is not None:
                y = y + prior(x)
            b.y[k] = y
            theta, omega = integrate(theta, y * y_std + y_mean, dt=dt, limits=limits)
        ctx.plan, ctx.buffers, ctx.weights = plan, b, weights
        y_hat = b.y.transpose(0, 1).contiguous()  # a copy: no output is kept on ctx
        h_out = torch.stack([h[-1] for h in b.h])
        c_out = torch.stack([c[-1] for c in b.c])
        ctx.mark_non_differentiable(h_out, c_out, theta, omega)
        return y_hat, h_out, c_out, theta, omega

    @staticmethod
    def backward(ctx: Any, g_yhat: torch.Tensor, *_: Any) -> tuple[Any, ...]:
        plan, b, weights = ctx.plan, ctx.buffers, ctx.weights
        net, norm, dt = plan.net, plan.norm, plan.dt
        n_layer, n_joint = net.cfg.n_layer, net.cfg.n_joint
        w1, w2 = weights[4 * n_layer], weights[4 * n_layer + 2]
        na, omega_in, residual = norm.n_angle, norm.omega_in, net.cfg.residual
        y_std, s_w = norm.y_std, norm.x_std[-n_joint:]
        n_step, n_batch = b.x.shape[:2]
        hidden = b.tc[0].shape[-1]
        # every sample's factors at once (ops over (n_step, n_batch, ...)):
        # the LSTM: dgates = [dc, dc, dc, dh] * lstm_p, dc = dh * lstm_q + dc',
        # lstm_p = [g, c, i, tanh c'] * [s'(i), s'(f), tanh'(g), s'(o)], lstm_q = o tanh'(c')
        # (s' = s (1 - s), tanh' = 1 - t^2)
        lstm_p, lstm_q, forget = [], [], []
        for layer in range(n_layer):
            act, tc = b.gates[layer], b.tc[layer]
            i, f, g, o = act.unsafe_chunk(4, -1)
            deriv = act * (1.0 - act)
            deriv[..., 2 * hidden : 3 * hidden] = 1.0 - g * g
            lstm_p.append(torch.cat([g, b.c[layer][:-1], i, tc], dim=-1).mul_(deriv))
            lstm_q.append(o * (1.0 - tc * tc))
            forget.append(f)
        # the angle features: d x / d theta per column (1 / x_std, times cos / -sin for the
        # sin / cos of a periodic joint), and a 0/1 map summing the columns into their joints
        jac = norm.x_std[:na].reciprocal().expand(n_step, n_batch, na).clone()
        to_joint = g_yhat.new_zeros(na, n_joint)
        col = 0
        for j, p in enumerate(norm.periodic):
            to_joint[col : col + 1 + p, j] = 1.0
            if p:
                th = b.theta[..., j]
                jac[..., col] *= torch.cos(th)
                jac[..., col + 1] *= -torch.sin(th)
            col += 1 + p
        # integrate: theta' = stop(theta + dt w_c), omega' = hit ? (theta' - theta)/dt : w_c;
        # its clip masks for every sample at once, from the same element-wise operations as
        # the forward pass's (so the same values): free where the speed bound did not clip,
        # hit where a stop did; moved: 0 where a stop was hit; pass_w: 0 there and where the
        # speed bound clipped
        limits = plan.limits
        if limits is not None:
            w_hat = b.y * y_std + norm.y_mean
            free = None
            if len(limits) == 3:
                w_c = torch.minimum(torch.maximum(w_hat, -limits[2]), limits[2])
                free = w_c == w_hat
            else:
                w_c = w_hat
            nxt = b.theta + dt * w_c
            hit = torch.minimum(torch.maximum(nxt, limits[0]), limits[1]) != nxt
            moved = (~hit).to(g_yhat.dtype)
            pass_w = moved if free is None else moved * free.to(g_yhat.dtype)
            back_dt = hit.to(g_yhat.dtype) / dt
            pass_ys = pass_w * y_std
        w_in = [weights[4 * k] for k in range(n_layer)]
        w_rec = [weights[4 * k + 1] for k in range(n_layer)]
        inv_s_w = s_w.reciprocal()
        g_theta = g_omega = None  # dL/dtheta[k+1], dL/domega[k+1] (none after the chunk)
        g_h: list[Any] = [None] * n_layer  # dL/dh, dL/dc of each layer's state after sample k
        g_c: list[Any] = [None] * n_layer
        g_pre = [g_yhat.new_empty(n_step, n_batch, 4 * hidden) for _ in range(n_layer)]
        g_y = g_yhat.new_empty(n_step, n_batch, n_joint)
        g_a1 = torch.empty_like(b.a1)
        for k in range(n_step - 1, -1, -1):
            if g_theta is None:
                g_y[k], g_th = g_yhat[:, k], None
            elif limits is None:
                torch.add(g_yhat[:, k], torch.add(g_omega, g_theta, alpha=dt) * y_std, out=g_y[k])
                g_th = g_theta
            else:
                back = g_omega * back_dt[k]  # through (theta' - theta) / dt, where stopped
                s = g_theta + back
                g_th = s * moved[k] - back  # theta' = theta + dt w_c where it moved
                torch.addcmul(g_yhat[:, k], torch.add(g_omega, s, alpha=dt), pass_ys[k], out=g_y[k])
            # head: a1 = W1 h + b1, y = W2 relu(a1) + b2; dL/dh of the top layer
            g = torch.ops.aten.threshold_backward.grad_input(
                g_y[k] @ w2, b.a1[k], 0.0, grad_input=g_a1[k]
            )
            top = n_layer - 1
            gh = g @ w1 if g_h[top] is None else torch.addmm(g_h[top], g, w1)
            for layer in range(top, -1, -1):
                q = lstm_q[layer][k]
                gc = gh * q if g_c[layer] is None else torch.addcmul(g_c[layer], gh, q)
                gp = torch.mul(
                    torch.cat([gc, gc, gc, gh], dim=1), lstm_p[layer][k], out=g_pre[layer][k]
                )
                # dL/d(input): the layer below's dL/dh (plus its own from sample k + 1)
                below = None if layer == 0 else g_h[layer - 1]
                gh = gp @ w_in[layer] if below is None else torch.addmm(below, gp, w_in[layer])
                g_h[layer] = gp @ w_rec[layer]
                g_c[layer] = gc * forget[layer][k]
            # encode: x = (raw - x_mean) / x_std, raw = (angles, commands, omega); the residual
            # head also read x's last columns
            g_x = gh
            g_feat = g_x[:, :na] * jac[k]
            g_theta = g_feat @ to_joint if g_th is None else torch.addmm(g_th, g_feat, to_joint)
            if omega_in:
                g_w = g_x[:, -n_joint:] + g_y[k] if residual else g_x[:, -n_joint:]
                g_omega = g_w * inv_s_w
            else:
                g_omega = torch.zeros_like(g_theta)
        # each weight's gradient over the whole chunk: one GEMM over its n_step * n_batch rows
        need = ctx.needs_input_grad
        out: list[torch.Tensor | None] = []
        rows = n_step * n_batch
        for layer in range(n_layer):
            gp = g_pre[layer].view(rows, -1)
            inp = b.x if layer == 0 else b.h[layer - 1][1:]
            wants = need[5 + 4 * layer : 9 + 4 * layer]
            db = gp.sum(0) if wants[2] or wants[3] else None
            out += [
                gp.t() @ inp.reshape(rows, -1) if wants[0] else None,
                gp.t() @ b.h[layer][:-1].reshape(rows, -1) if wants[1] else None,
                db if wants[2] else None,
                db if wants[3] else None,
            ]
        g_yc, g_a1c = g_y.view(rows, -1), g_a1.view(rows, -1)
        out += [
            g_a1c.t() @ b.h[-1][1:].reshape(rows, -1),
            g_a1c.sum(0),
            g_yc.t() @ F.relu(b.a1.view(rows, -1)),
            g_yc.sum(0),
        ]
        return (None, None, None, None, None, *out)


def free_run_chunk(
    net: SurrogateNet,
    norm: Normalization,
    *,
    theta: torch.Tensor,
    omega: torch.Tensor,
    state: State,
    u: torch.Tensor,
    z: torch.Tensor,
    dt: float,
    limits: tuple[torch.Tensor, ...] | None,
) -> tuple[torch.Tensor, State, torch.Tensor, torch.Tensor]:
    """One free-run TBPTT chunk (see the module docstring); only the weights get gradients.

    Args:
        net: a network :func:`supported` accepts (its parameters may require grad).
        norm: the features' normalisation.
        theta: (n_batch, n_joint) angles at the chunk's first sample [rad] (a constant).
        omega: (n_batch, n_joint) their velocity feature [rad/s] (a constant).
        state: ``(h, c)``, each (n_layer, n_batch, hidden) (a constant).
        u: (n_batch, n_step, n_u) the chunk's commands [command units].
        z: (n_batch, n_step, P + L, n_joint) the command states after them.
        dt: sample period [s].
        limits: end stops (and speed bounds) as in :func:`~..surrogate.angles.integrate`.

    Returns:
        ``y_hat`` (n_batch, n_step, n_joint) normalised velocities (differentiable in the
        weights), the state after the chunk, and ``theta``, ``omega`` after its last sample.
    """
    with torch.no_grad():
        cmd = _commands(norm, u, z)
    plan = _Plan(net=net, norm=norm, dt=dt, limits=limits)
    y_hat, h, c, theta, omega = _Chunk.apply(plan, theta, omega, state, cmd, *_weights(net))
    return y_hat, (h, c), theta, omega
