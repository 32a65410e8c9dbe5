"""A small synthetic hydraulic-like plant for tests and benchmarks (no MuJoCo needed).

Per joint ``j`` (any number of joints; the first may be periodic like a swing):

    d = deadzone(u_j(t - delay) / u_scale_j)
    v' = (K_j * d * (1 - g_j * sign(d) * cos(theta)) - v) / tau_j - c * v * |v|
    theta' = v

integrated with ``substeps`` Euler steps per sample; non-periodic joints stop at their limits.
Recorded like the data contract: ``theta[k]`` at ``t_k``, ``u[k]`` held over
``[t_k, t_{k+1})``, ``omega[k]`` = mean velocity over ``[t_{k-1}, t_k]`` (so
``theta[k] = theta[k-1] + T_s * omega[k]``), plus ``theta_true``/``omega_true``; measured
``theta`` gets optional Gaussian noise.  Periodic angles are stored wrapped to ``[-pi, pi)``.

Excitations: ``sine`` (sums of random sinusoids, like the paper's training set) and ``step``
(random piecewise-constant commands, like its test set, chosen online by a simple "operator"
that steers away from the joint stops).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from ..data.dataset import write_dataset
from ..data.episode import Episode
from ..spec import JointSpec, MachineSpec
from .angles import wrap_angle

_NAMES = ("swing", "boom", "arm", "bucket", "wrist", "tilt", "j6", "j7")


def synthetic_spec(
    n_joint: int = 3, *, periodic_first: bool = True, rate_hz: float = 20.0
) -> MachineSpec:
    """A machine with ``n_joint`` joints (first periodic if asked), commands in [-1000, 1000]."""
    joints = []
    for j in range(n_joint):
        name = _NAMES[j] if j < len(_NAMES) else f"j{j}"
        if j == 0 and periodic_first:
            joints.append(JointSpec(name, periodic=True))
        else:
            joints.append(JointSpec(name, theta_min=-1.2, theta_max=1.2))
    return MachineSpec(joints=tuple(joints), rate_hz=rate_hz, name=f"synthetic-{n_joint}j")


def _commands(
    kind: str, n_step: int, n_joint: int, rng: np.random.Generator, dt: float
) -> np.ndarray:
    t = np.arange(n_step) * dt
    u = np.zeros((n_step, n_joint))
    if kind == "sine":
        for j in range(n_joint):
            for _ in range(3):
                f = rng.uniform(0.05, 0.5)
                a = rng.uniform(120, 380)
                u[:, j] += a * np.sin(2 * math.pi * f * t + rng.uniform(0, 2 * math.pi))
    elif kind == "step":
        pass  # chosen online from the simulated pose (see synthetic_episode)
    else:
        raise ValueError(f"unknown excitation '{kind}' (sine or step)")
    return np.clip(u, -1000.0, 1000.0)


def _advance(
    theta: list[float],
    v: list[float],
    drive: list[float],
    gain: list[float],
    grav: list[float],
    tau: list[float],
    lo: list[float],
    hi: list[float],
    *,
    drag: float,
    h: float,
    substeps: int,
) -> None:
    """``substeps`` Euler steps of the module's equations, in place on ``theta`` and ``v``
    (per joint, [rad] and [rad/s]).  The joints do not couple, so each is stepped alone in
    plain floats: the same IEEE operations in the same order as on arrays, without an array
    call per operation (the fixtures of many tests are made here)."""
    for j, d in enumerate(drive):
        kd, gs = gain[j] * d, grav[j] * ((d > 0.0) - (d < 0.0))  # K d, g sign(d)
        th, vj = theta[j], v[j]
        for _ in range(substeps):
            # v' = (K d (1 - g sign(d) cos theta) - v) / tau - c v |v|
            acc = (kd * (1.0 - gs * math.cos(th)) - vj) / tau[j] - drag * vj * abs(vj)
            vj = vj + h * acc
            th = th + h * vj
            if th < lo[j]:  # an end stop: the joint rests on it
                th, vj = lo[j], 0.0
            elif th > hi[j]:
                th, vj = hi[j], 0.0
        theta[j], v[j] = th, vj


def synthetic_episode(
    spec: MachineSpec,
    *,
    kind: Literal["sine", "step"] = "sine",
    n_step: int = 600,
    seed: int = 0,
    noise: float = 0.0,
    delay: int = 1,
    substeps: int = 10,
    name: str | None = None,
) -> Episode:
    """Simulate one episode of the synthetic plant.

    Args:
        spec: machine (see :func:`synthetic_spec`).
        kind: ``sine`` or ``step`` commands.
        n_step: samples.
        seed: RNG seed (commands, noise, initial pose).
        noise: std of Gaussian noise on measured angles [rad].
        delay: command delay [samples].
        substeps: Euler sub-steps per sample.
    """
    rng = np.random.default_rng(seed)
    nj = spec.n_joint
    dt = spec.dt
    u = _commands(kind, n_step, nj, rng, dt)
    next_change = np.zeros(nj, dtype=int)
    # sine: a slow random target pose, tracked by a P term on top of the sines, covers the range
    t = np.arange(n_step) * dt
    pose = 0.7 * np.sin(
        2 * math.pi * rng.uniform(0.005, 0.02, nj)[None] * t[:, None]
        + rng.uniform(0, 2 * math.pi, nj)
    )
    idx = np.arange(nj)
    gain = 0.35 + 0.1 * (idx % 3)  # rad/s at full command
    tau = 0.15 + 0.05 * (idx % 2)  # s
    grav = np.where(np.array(spec.periodic), 0.0, 0.15)  # load asymmetry (lifting is slower)
    drag = 0.5
    dz = 0.08  # dead zone, fraction of full command
    scale = np.array([j.u_scale for j in spec.joints])
    center = np.array([j.u_center for j in spec.joints])
    lo = np.array([j.theta_min if j.theta_min is not None else -np.inf for j in spec.joints])
    hi = np.array([j.theta_max if j.theta_max is not None else np.inf for j in spec.joints])
    th_true = np.empty((n_step, nj))
    th_true[0] = np.where(
        np.isfinite(lo), rng.uniform(-0.3, 0.3, nj), rng.uniform(-math.pi, math.pi, nj)
    )
    th, v = th_true[0].tolist(), [0.0] * nj  # the state that _advance steps
    h = dt / substeps
    plant = (gain.tolist(), grav.tolist(), tau.tolist(), lo.tolist(), hi.tolist())
    for k in range(n_step - 1):
        theta = th_true[k]  # the pose at t_k, which the operator and the tracking read
        if kind == "step":  # an operator: random steps, heading away from the stops when close
            for j in np.flatnonzero(next_change <= k):
                level = 0.0 if rng.random() < 0.3 else rng.uniform(150.0, 700.0)
                sign = rng.choice([-1.0, 1.0])
                if np.isfinite(lo[j]):
                    mid, half = 0.5 * (lo[j] + hi[j]), 0.5 * (hi[j] - lo[j])
                    if abs(theta[j] - mid) > 0.5 * half:
                        sign = -np.sign(theta[j] - mid)
                u[k:, j] = sign * level
                next_change[j] = k + int(rng.integers(int(1.0 / dt), int(4.0 / dt)))
        elif kind == "sine":
            track = np.isfinite(lo)
            u[k, track] = np.clip(
                u[k, track] + 600.0 * (pose[k, track] - theta[track]), -1000.0, 1000.0
            )
        ud = (u[max(k - delay, 0)] - center) / scale
        drive = np.sign(ud) * np.maximum(np.abs(ud) - dz, 0.0) / (1 - dz)
        _advance(th, v, drive.tolist(), *plant, drag=drag, h=h, substeps=substeps)
        th_true[k + 1] = th
    om_true = np.zeros_like(th_true)
    om_true[1:] = np.diff(th_true, axis=0) / dt
    per = np.array(spec.periodic)
    th_store = th_true.copy()
    th_store[:, per] = wrap_angle(th_store[:, per])
    th_meas = th_store + (rng.normal(0.0, noise, th_store.shape) if noise > 0 else 0.0)
    om_meas = np.zeros_like(th_meas)
    d = np.diff(th_meas, axis=0)
    d[:, per] = wrap_angle(d[:, per])
    om_meas[1:] = d / dt
    return Episode(
        spec=spec,
        time=np.arange(n_step) * dt,
        u=u,
        theta=th_meas,
        omega=om_meas,
        theta_true=th_store,
        omega_true=om_true,
        source="synthetic",
        condition=kind,
        seed=seed,
        generator={"kind": kind, "n_step": n_step, "noise": noise, "delay": delay},
        name=name or f"{kind}_{seed:04d}",
    )


def synthetic_split(
    spec: MachineSpec,
    *,
    n_train: int = 4,
    n_val: int = 1,
    n_test: int = 1,
    n_step: int = 600,
    test_steps: int | None = None,
    noise: float = 0.0,
    seed: int = 0,
) -> list[tuple[Episode, str]]:
    """``(episode, split)`` pairs: sine episodes for train/val, step episodes for test."""
    items: list[tuple[Episode, str]] = []
    s = seed * 1000
    for i in range(n_train):
        items.append(
            (synthetic_episode(spec, kind="sine", n_step=n_step, seed=s + i, noise=noise), "train")
        )
    for i in range(n_val):
        items.append(
            (
                synthetic_episode(spec, kind="sine", n_step=n_step, seed=s + 100 + i, noise=noise),
                "val",
            )
        )
    for i in range(n_test):
        items.append(
            (
                synthetic_episode(
                    spec, kind="step", n_step=test_steps or n_step, seed=s + 200 + i, noise=noise
                ),
                "test",
            )
        )
    return items


def write_synthetic_dataset(out: str | Path, spec: MachineSpec | None = None, **kw: object) -> Path:
    """Write a synthetic dataset folder (see :func:`synthetic_split` for keywords)."""
    spec = spec or synthetic_spec()
    items: Sequence[tuple[Episode, str]] = synthetic_split(spec, **kw)  # type: ignore[arg-type]
    return write_dataset(
        out, items, config={"synthetic": {k: v for k, v in kw.items() if v is not None}}
    )
