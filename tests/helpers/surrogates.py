"""Tiny untrained surrogates for tests (no training needed)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from excavator_surrogate.data import Episode
from excavator_surrogate.spec import EXCAVATOR, MachineSpec
from excavator_surrogate.surrogate.angles import joint_limits
from excavator_surrogate.surrogate.features import Normalization
from excavator_surrogate.surrogate.model import ModelConfig, Surrogate, build_net
from excavator_surrogate.surrogate.parallel import with_parallel_map
from excavator_surrogate.surrogate.reference import rollout_reference
from excavator_surrogate.surrogate.rollout import rollout
from excavator_surrogate.surrogate.series import with_map_joints


def drive_into_stops(net: nn.Module, drive: float, n_joint: int) -> None:
    """Add ``+/- drive`` (alternating by joint, normalised units) to the output bias of an
    untrained surrogate network so that its free runs reach the joint limits (end-stop tests)."""
    if not drive:
        return
    last = net.linear if hasattr(net, "linear") else net.head[-1]
    with torch.no_grad():
        last.bias += drive * torch.tensor([(-1.0) ** j for j in range(n_joint)])


def tiny_surrogate(
    spec: MachineSpec = EXCAVATOR,
    episodes: Sequence[Episode] | None = None,
    *,
    mode: str = "stateful",
    cell: str = "lstm",
    window: int = 6,
    hidden: int = 16,
    seed: int = 0,
    end_stops: bool = False,
    drive: float = 0.0,
    play: tuple[float, ...] = (),
    omega_in: bool = False,
    residual: bool = False,
    prior: bool = False,
) -> Surrogate:
    """An untrained 2-layer surrogate of ``spec`` (weights from ``torch.manual_seed(seed)``).

    The normalisation is fitted on ``episodes`` if given, else drawn from ``seed`` (non-trivial
    feature statistics, slow bounded output: omega std 0.05 rad/s).  ``play``: half-widths of
    command play features (inputs widen by ``len(play) * n_joint``); ``omega_in``: the
    velocity feature (inputs widen by ``n_joint``); ``residual``: the head adds it (needs
    ``omega_in``); ``prior``: a speed prior, the same map for every ``seed`` (so members
    merge) with dead zones and gains drawn from a fixed generator.  ``drive`` adds
    +/- ``drive`` (alternating by joint, normalised units) to the output bias so that free runs
    reach the joint limits (end-stop tests).
    """
    torch.manual_seed(seed)
    n_feature = spec.n_feature + (len(play) + omega_in) * spec.n_joint
    cfg = ModelConfig(
        n_feature=n_feature,
        n_joint=spec.n_joint,
        window=window,
        hidden=hidden,
        n_layer=2,
        cell=cell,
        head_hidden=hidden,
        residual=residual,
        prior=prior,
    )
    if episodes is not None:
        norm = Normalization.fit(
            [e.theta for e in episodes], [e.u for e in episodes], spec, play=play, omega_in=omega_in
        )
    else:
        rng = np.random.default_rng(seed)
        norm = Normalization.from_arrays(
            x_mean=rng.normal(size=n_feature) * 0.1,
            x_std=1.0 + rng.random(n_feature),
            y_mean=np.zeros(spec.n_joint),
            y_std=np.full(spec.n_joint, 0.05),
            spec=spec,
            play=play,
            omega_in=omega_in,
        )
    net = build_net(cfg).eval()
    if prior:
        rng = np.random.default_rng(1234)  # one map for every seed: members merge
        u_max = np.array([j.u_max for j in spec.joints])
        net.prior.load_fit(
            cols=[spec.n_angle_feature + j for j in range(spec.n_joint)],
            a_pos=rng.uniform(0.0, 0.3, spec.n_joint) * u_max,
            a_neg=-rng.uniform(0.0, 0.3, spec.n_joint) * u_max,
            k_pos=rng.uniform(0.1, 0.5, spec.n_joint) / u_max,
            k_neg=rng.uniform(0.1, 0.5, spec.n_joint) / u_max,
            norm=norm,
        )
    drive_into_stops(net, drive, spec.n_joint)
    return Surrogate(
        net=net, spec=spec, norm=norm, model_cfg=cfg, mode=mode, name=cell, end_stops=end_stops
    )


def make_surrogate(
    spec: MachineSpec,
    episodes: Sequence[Episode],
    *,
    mode: str = "windowed",
    window: int = 8,
    hidden: int = 12,
    **kw,
) -> Surrogate:
    """:func:`tiny_surrogate` with the normalisation fitted on ``episodes`` (windowed, W = 8,
    12 units unless given)."""
    return tiny_surrogate(spec, episodes, mode=mode, window=window, hidden=hidden, **kw)


VARIANTS: dict[str, dict] = {
    "free": dict(end_stops=False, play=(), omega_in=False),
    "stops": dict(end_stops=True, play=(), omega_in=False),
    "play": dict(end_stops=False, play=(0.05, 0.2), omega_in=False),
    "velocity": dict(end_stops=True, play=(0.05,), omega_in=True),
    "prior": dict(end_stops=True, play=(), omega_in=False, prior=True),
    "delayed-map": dict(end_stops=False, play=(0.05,), omega_in=False, delayed_map=True),
    "parallel-map": dict(end_stops=True, play=(0.05,), omega_in=True, parallel_map=True),
}
"""The runtime-equivalence tests' surrogate variants (keyword arguments of
:func:`variant_surrogate` besides ``mode`` and ``cell``), by test id."""


def variant_surrogate(
    *,
    mode: str,
    cell: str,
    end_stops: bool,
    play: tuple[float, ...],
    omega_in: bool,
    prior: bool = False,
    delayed_map: bool = False,
    parallel_map: bool = False,
) -> Surrogate:
    """:func:`tiny_surrogate` for the runtime-equivalence tests: with end stops it is driven
    into them, a velocity feature comes with the residual head, ``prior`` gives a speed
    prior (both where the cell has a head: not ARX, which then runs without them), and
    ``delayed_map`` puts the swing and the bucket on a static map with delays 2 and 0
    (:func:`on_static_map`; LSTM/GRU without a head only); ``parallel_map`` puts them on it
    in parallel (:func:`on_parallel_map`, delays 2 and 0, with end stops tighter than the
    network's; LSTM/GRU only)."""
    sur = tiny_surrogate(
        mode=mode,
        cell=cell,
        end_stops=end_stops,
        drive=20.0 if end_stops else 0.0,
        play=play,
        omega_in=omega_in,
        residual=omega_in and cell != "arx" and not prior,
        prior=prior and cell != "arx",
    )
    if parallel_map and cell != "arx":
        return on_parallel_map(sur, delay=(2, 0, 0, 0), stops=end_stops)
    return on_static_map(sur, delay=(2, 0, 0, 0)) if delayed_map and cell != "arx" else sur


PARALLEL_JOINTS = [True, False, False, True]
"""The joints :func:`on_parallel_map` puts on the map (swing and bucket)."""


def map_fit(spec: MachineSpec, delay: tuple[int, ...] | None = None) -> dict:
    """A static map for every joint of ``spec`` with a gain spread (the test maps)."""
    n_j = spec.n_joint
    fit = {
        "cols": [spec.n_angle_feature + j for j in range(n_j)],
        "a_pos": [50.0] * n_j,
        "a_neg": [-80.0] * n_j,
        "k_pos": [1e-3] * n_j,
        "k_neg": [8e-4] * n_j,
        "gain_spread": [0.2, 0.1, 0.1, 0.3],
    }
    if delay is not None:
        fit["delay"] = list(delay)
    return fit


def tight_stops(spec: MachineSpec) -> tuple[np.ndarray, np.ndarray]:
    """End stops 30 % of each joint's range inside the spec's (``(lo, hi)``, (n_joint,) each
    [rad]; +-inf where it has none): tighter than the network's, as a map joint's may be."""
    lo, hi = joint_limits(spec)
    span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    return lo + 0.3 * span, hi - 0.3 * span


def on_parallel_map(sur, *, delay: tuple[int, ...] | None = None, stops: bool = False):
    """``sur`` with the swing and the bucket on :func:`map_fit`'s map in parallel (the
    network reads its own angles of them); ``stops``: the map joints stop at
    :func:`tight_stops` (the network keeps its own)."""
    map_stops = tight_stops(sur.spec) if stops else None
    return with_parallel_map(sur, map_fit(sur.spec, delay), PARALLEL_JOINTS, map_stops=map_stops)


def on_static_map(sur, *, delay: tuple[int, ...] | None = None):
    """``sur`` with the swing and the bucket on a static map with a gain spread (members
    drive them with gains 1 + sigma z_m), reading commands ``delay`` samples back (per
    joint; None: no delay)."""
    return with_map_joints(sur, map_fit(sur.spec, delay), [True, False, False, True])


def free_run_checked(sur: Surrogate, ep: Episode, n_step: int = 80) -> np.ndarray:
    """The free run of ``sur`` on the first ``n_step`` samples of ``ep``, asserted equal to the
    plain loop (angles, and velocities after the window); returns the velocities
    ``(n_step, n_joint)`` [rad/s]."""
    theta, u = ep.theta[None, :n_step], ep.u[None, :n_step]
    th, om = rollout(sur, theta, u)
    th_ref, om_ref = rollout_reference(sur, theta[0], u[0])
    np.testing.assert_allclose(th[0], th_ref, atol=1e-5)
    w = sur.window
    np.testing.assert_allclose(om[0, w:], om_ref[w:], atol=1e-5)
    return om[0]


def teacher_forced_omega(sur: Surrogate, ep: Episode, n_step: int | None = None) -> torch.Tensor:
    """The network's one-step omega (n_step, n_joint) [rad/s] on the episode's first
    ``n_step`` samples (all by default), teacher-forced on the measured angles."""
    th = torch.tensor(ep.theta[:n_step], dtype=torch.float32)
    u = torch.tensor(ep.u[:n_step], dtype=torch.float32)
    z = sur.norm.play_seq(sur.norm.play_rest(1), u[None])[0] if sur.norm.n_state else None
    with torch.no_grad():
        y, _ = sur.net.forward_seq(sur.norm.encode(th, u, z)[None])
    return sur.norm.omega(y)[0]
