"""The hand-written free-run chunk (training.free_run) against the autograd reference: the
same predictions and the same weight gradients, in float64 to rounding, for every network
and feature variant it accepts; and the training mode's two paths agree in float32."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.spec import EXCAVATOR, InputSpec, MachineSpec
from excavator_surrogate.surrogate.angles import integrate
from excavator_surrogate.surrogate.model import Surrogate
from excavator_surrogate.training.batches import make_data
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.free_run import free_run_chunk, supported
from excavator_surrogate.training.modes import make_mode
from tests.helpers.surrogates import make_surrogate, on_static_map, tiny_surrogate


def _bounded(spec: MachineSpec = EXCAVATOR) -> MachineSpec:
    """``spec`` with a speed bound on every joint (0.12 rad/s): the driven free runs clip at
    it."""
    return replace(spec, joints=tuple(replace(j, omega_max=0.12) for j in spec.joints))


def _reference(sur: Surrogate, *, theta, omega, state, u, z, limits):
    """The autograd path of ``Stateful.predict``: one encode / cell step / integration per
    sample."""
    norm, net, dt = sur.norm, sur.net, sur.spec.dt
    ys = []
    for k in range(u.shape[1]):
        x = norm.encode(theta, u[:, k], z[:, k], omega)
        y, state = net.step(x, state)
        theta, omega = integrate(theta, norm.omega(y), dt=dt, limits=limits)
        ys.append(y)
    return torch.stack(ys, dim=1), state, theta, omega


CASES = {
    "plain": dict(spec=EXCAVATOR, end_stops=False),
    "stops": dict(spec=EXCAVATOR, end_stops=True, drive=3.0),
    "stops+speed": dict(spec=_bounded(), end_stops=True, drive=3.0),
    "play": dict(spec=_bounded(), end_stops=True, drive=1.0, play=(0.05, 0.2)),
    "residual": dict(
        spec=_bounded(), end_stops=True, drive=1.0, play=(0.05,), omega_in=True, residual=True
    ),
    "velocity, no residual": dict(spec=EXCAVATOR, end_stops=True, drive=1.0, omega_in=True),
    "prior": dict(spec=_bounded(), end_stops=True, drive=1.0, prior=True),
    "exogenous input": dict(
        spec=replace(_bounded(), inputs=(InputSpec("throttle", u_min=0.0, u_max=1.0),)),
        end_stops=True,
        drive=1.0,
        play=(0.05,),
        omega_in=True,
        residual=True,
    ),
    "delayed map": dict(spec=EXCAVATOR, end_stops=True, play=(0.05,), delayed=True),
}


def _case(name: str) -> Surrogate:
    kw = dict(CASES[name])
    delayed = kw.pop("delayed", False)
    sur = tiny_surrogate(kw.pop("spec"), mode="stateful", hidden=12, **kw)
    return on_static_map(sur, delay=(2, 0, 1, 0)) if delayed else sur


def _inputs(sur: Surrogate, n_batch: int, n_step: int, dtype: torch.dtype, seed: int = 0):
    """Random start angles inside the limits (two samples next to the stops), velocities, states and command sequences (with
    their command states from rest), as the training mode hands them over."""
    rng = np.random.default_rng(seed)
    spec, norm = sur.spec, sur.norm
    lo = np.array([-np.pi if j.periodic else j.theta_min for j in spec.joints])
    hi = np.array([np.pi if j.periodic else j.theta_max for j in spec.joints])
    theta = rng.uniform(lo, hi, (n_batch, spec.n_joint))
    theta[0], theta[1] = hi - 0.005, lo + 0.005  # next to the end stops (a periodic joint: +/- pi)
    omega = rng.normal(0.0, 0.1, (n_batch, spec.n_joint))
    u = rng.uniform(-1000.0, 1000.0, (n_batch, n_step, spec.n_u))
    z = norm.play_from_rest_np(u, spec)
    if z is None:
        z = np.zeros((n_batch, n_step, 0, spec.n_joint))
    h = rng.normal(0.0, 0.5, (2, 2, n_batch, sur.model_cfg.hidden))

    def t(a):
        return torch.as_tensor(a, dtype=dtype)

    return dict(theta=t(theta), omega=t(omega), state=(t(h[0]), t(h[1])), u=t(u), z=t(z))


def _run(sur: Surrogate, fused: bool, inputs: dict, target: torch.Tensor):
    """Predictions, end state and weight gradients of one chunk under a smooth-L1 loss."""
    net = sur.net
    net.zero_grad(set_to_none=True)
    limits = sur.limits()
    if fused:
        out = free_run_chunk(net, sur.norm, dt=sur.spec.dt, limits=limits, **inputs)
    else:
        out = _reference(sur, limits=limits, **inputs)
    torch.nn.functional.smooth_l1_loss(out[0], target).backward()
    grads = {n: p.grad.detach().clone() for n, p in net.named_parameters()}
    return out, grads


@pytest.mark.parametrize("name", list(CASES))
def test_chunk_equals_the_autograd_reference_in_float64(name: str) -> None:
    sur = _case(name)
    sur.net.double().train()
    sur.norm = sur.norm.to("cpu", dtype=torch.float64)
    assert supported(sur.net)
    inputs = _inputs(sur, n_batch=5, n_step=12, dtype=torch.float64)
    target = torch.randn(
        5, 12, sur.spec.n_joint, dtype=torch.float64, generator=torch.Generator().manual_seed(1)
    )
    (y_f, st_f, th_f, om_f), g_f = _run(sur, True, inputs, target)
    (y_r, st_r, th_r, om_r), g_r = _run(sur, False, inputs, target)
    torch.testing.assert_close(y_f, y_r, rtol=1e-12, atol=1e-12)
    for a, b in zip((*st_f, th_f, om_f), (*st_r, th_r, om_r)):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
        assert not a.requires_grad
    assert g_f.keys() == g_r.keys()
    for n in g_r:
        scale = g_r[n].abs().max().item()
        torch.testing.assert_close(g_f[n], g_r[n], rtol=1e-9, atol=1e-12 * max(scale, 1.0), msg=n)
    if CASES[name].get("drive"):  # the clipping branches were exercised
        lim = sur.limits()
        at_stop = (th_r <= lim[0]) | (th_r >= lim[1])
        assert at_stop.any()


def test_the_cases_reach_the_speed_bound() -> None:
    """``stops+speed`` drives the joints past their speed bound (so the clip mask is tested)."""
    sur = _case("stops+speed")
    inputs = _inputs(sur, n_batch=5, n_step=12, dtype=torch.float32)
    with torch.no_grad():
        x = sur.norm.encode(inputs["theta"], inputs["u"][:, 0], inputs["z"][:, 0], inputs["omega"])
        y, _ = sur.net.step(x, inputs["state"])
    assert (sur.norm.omega(y).abs() > 0.12).any()


def test_weights_without_grad_get_none_and_gru_is_not_supported() -> None:
    sur = _case("residual")
    sur.net.train()
    sur.net.rnn.weight_hh_l0.requires_grad_(False)
    inputs = _inputs(sur, n_batch=3, n_step=4, dtype=torch.float32)
    y, *_ = free_run_chunk(sur.net, sur.norm, dt=sur.spec.dt, limits=sur.limits(), **inputs)
    y.square().mean().backward()
    assert sur.net.rnn.weight_hh_l0.grad is None
    assert sur.net.rnn.weight_ih_l0.grad is not None
    assert not supported(tiny_surrogate(mode="stateful", cell="gru").net)


def test_stateful_mode_fused_and_autograd_pieces_agree(spec, episodes) -> None:
    """``Stateful.predict`` with ``fused_backward`` on and off: the same pieces and, after each
    piece's backward, the same gradients (float32: to rounding)."""
    sur = make_surrogate(
        spec, episodes, mode="stateful", end_stops=True, omega_in=True, residual=True, play=(0.1,)
    )
    sur.net.train()
    data = make_data(episodes, sur.norm, torch.device("cpu"))
    base = TrainConfig(
        mode="stateful",
        seq_len=24,
        burn_in=5,
        tbptt=6,
        seq_batch=4,
        feedback="free",
        teacher_epochs=0,
        velocity_input=True,
        residual=True,
        play=(0.1,),
    )
    index = np.array([0, 9, 30, 81])
    pieces = {}
    for fused in (True, False):
        net = copy.deepcopy(sur.net)
        s = replace(sur, net=net)
        mode = make_mode(replace(base, fused_backward=fused), data, s)
        assert mode._fused is fused
        got = []
        for y_hat, y, _ in mode.predict(net, index, epoch=3):
            net.zero_grad(set_to_none=True)
            torch.nn.functional.smooth_l1_loss(y_hat, y.nan_to_num()).backward()
            got.append((y_hat.detach(), [p.grad.clone() for p in net.parameters()]))
        pieces[fused] = got
    assert len(pieces[True]) == len(pieces[False]) == 4
    for (y_f, g_f), (y_r, g_r) in zip(pieces[True], pieces[False]):
        torch.testing.assert_close(y_f, y_r, rtol=1e-5, atol=1e-6)
        for a, b in zip(g_f, g_r):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6 * max(b.abs().max().item(), 1.0))
