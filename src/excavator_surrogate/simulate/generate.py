"""Generate simulated datasets: excitation -> MuJoCo plant -> episode files.

:func:`simulate_dataset` writes a dataset folder (see :mod:`excavator_surrogate.data`) with
``train``, ``val`` and ``test`` episodes.  Episodes are simulated in parallel processes;
the output is identical for a given seed whatever the number of workers, because every
episode draws from its own seed: ``SeedSequence(seed)`` spawns one child per split (train,
val, test) and each split's child spawns one seed per episode, so e.g. the test episodes do
not change when ``n_train`` changes.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import config as config_mod
from ..data import Episode, write_dataset
from ..errors import ConfigError
from ..io_utils import log, progress
from ..spec import EXCAVATOR, MachineSpec
from .excitation import SIGNALS, ExcitationConfig, generate
from .plant import MujocoExcavator, PlantConfig

SOURCE = "mujoco-ideal"
"""``source`` metadata of episodes from the ideal Stage I plant."""


@dataclass(frozen=True)
class SimulateConfig:
    """What ``exsur simulate`` generates (TOML table ``[simulate]``)."""

    n_train: int = 12
    """Training episodes."""
    n_val: int = 2
    """Validation episodes (model selection; not in the paper)."""
    n_test: int = 1
    """Test episodes (unseen signal kind in the paper: steps)."""
    steps_train: int = 5300
    """Samples per training episode (at rate_hz)."""
    steps_val: int = 5300
    """Samples per validation episode."""
    steps_test: int = 1800
    """Samples per test episode."""
    train_signals: tuple[str, ...] = ("multisine",)
    """Signal kinds of training episodes, used in turn (episode i uses kind i mod len)."""
    val_signals: tuple[str, ...] = ("multisine",)
    """Signal kinds of validation episodes, used in turn."""
    test_signals: tuple[str, ...] = ("steps",)
    """Signal kinds of test episodes, used in turn."""
    seed: int = 0
    """Root seed; every episode gets its own child seed."""
    workers: int = 1
    """Parallel processes (output does not depend on it)."""
    rate_hz: float = 20.0
    """Sample (control) rate [Hz]."""
    delay_s: float = 0.05
    """Actuation delay [s]."""
    xml: str = ""
    """MJCF file; empty = the packaged excavator."""
    pose_margin: float = 0.1
    """Random initial poses keep this fraction of each joint's range from its limits."""
    limit_margin: float = 0.05
    """Excitation keeps the nominal angle this far from the end stops [rad]."""
    condition: str = "noload"
    """Operating condition recorded in the episodes."""
    record_truth: bool = True
    """Also write theta_<j>_true / omega_<j>_true (equal to the measured columns here)."""
    excitation: ExcitationConfig = field(default_factory=ExcitationConfig)
    """Parameters of the signal kinds (``[simulate.excitation.<kind>]``)."""

    def __post_init__(self) -> None:
        for name in ("n_train", "n_val", "n_test"):
            if getattr(self, name) < 0:
                raise ConfigError(f"simulate.{name} must be >= 0, got {getattr(self, name)}")
        for name in ("steps_train", "steps_val", "steps_test"):
            if getattr(self, name) < 2:
                raise ConfigError(f"simulate.{name} must be >= 2, got {getattr(self, name)}")
        for name in ("train_signals", "val_signals", "test_signals"):
            kinds = getattr(self, name)
            if not kinds:
                raise ConfigError(f"simulate.{name} must list at least one signal kind")
            bad = [k for k in kinds if k not in SIGNALS]
            if bad:
                raise ConfigError(
                    f"simulate.{name}: unknown signal kind(s) {bad}; choose from {', '.join(SIGNALS)}"
                )
        if self.n_train + self.n_val + self.n_test == 0:
            raise ConfigError("simulate: n_train + n_val + n_test is 0, nothing to generate")
        if self.workers < 1:
            raise ConfigError(f"simulate.workers must be >= 1, got {self.workers}")
        if not 0 <= self.pose_margin < 0.5:
            raise ConfigError(f"simulate.pose_margin must be in [0, 0.5), got {self.pose_margin}")

    def plant_config(self) -> PlantConfig:
        """The plant options implied by this config (single-threaded: parallelism is per process)."""
        return PlantConfig(xml=self.xml, rate_hz=self.rate_hz, delay_s=self.delay_s, n_threads=1)


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to simulate (picklable, sent to worker processes)."""

    split: str
    """``train``, ``val`` or ``test``."""
    index: int
    """Index within the split."""
    kind: str
    """Signal kind."""
    n_step: int
    """Samples."""
    seed: int
    """Episode seed (``numpy.random.default_rng(seed)`` reproduces the episode)."""

    @property
    def name(self) -> str:
        """Episode name (file stem)."""
        return f"{self.split}_{self.index:03d}"


def plan_episodes(cfg: SimulateConfig) -> list[EpisodeJob]:
    """The episodes of ``cfg`` in dataset order (train, val, test), each with its own seed."""
    root = np.random.SeedSequence(cfg.seed)
    split_seqs = root.spawn(3)
    jobs: list[EpisodeJob] = []
    plan = (
        ("train", cfg.n_train, cfg.steps_train, cfg.train_signals),
        ("val", cfg.n_val, cfg.steps_val, cfg.val_signals),
        ("test", cfg.n_test, cfg.steps_test, cfg.test_signals),
    )
    for (split, n, n_step, kinds), seq in zip(plan, split_seqs):
        for i, child in enumerate(seq.spawn(n)):
            seed = int(child.generate_state(1, dtype=np.uint32)[0])
            jobs.append(EpisodeJob(split, i, kinds[i % len(kinds)], n_step, seed))
    return jobs


def random_pose(rng: np.random.Generator, spec: MachineSpec, *, margin: float = 0.1) -> np.ndarray:
    """(n_joint,) random angles [rad]: uniform inside each range shrunk by ``margin`` x range
    at both ends; uniform in [-pi, pi) for unlimited joints."""
    out = np.empty(spec.n_joint)
    for k, j in enumerate(spec.joints):
        if j.theta_min is None or j.theta_max is None:
            out[k] = rng.uniform(-np.pi, np.pi)
        else:
            span = j.theta_max - j.theta_min
            out[k] = rng.uniform(j.theta_min + margin * span, j.theta_max - margin * span)
    return out


_PLANTS: dict[tuple[Any, ...], MujocoExcavator] = {}


def _plant(cfg: SimulateConfig, spec: MachineSpec) -> MujocoExcavator:
    """One cached plant per process and configuration."""
    key = (cfg.xml, cfg.rate_hz, cfg.delay_s, spec)
    if key not in _PLANTS:
        _PLANTS[key] = MujocoExcavator(cfg.plant_config(), spec=spec)
    return _PLANTS[key]


def simulate_episode(
    job: EpisodeJob, cfg: SimulateConfig, *, spec: MachineSpec = EXCAVATOR
) -> dict[str, np.ndarray]:
    """Simulate one planned episode.

    Returns:
        ``theta0`` (n_joint,), ``u``, ``theta``, ``omega`` (n_step, n_joint).
    """
    plant = _plant(cfg, spec)
    rng = np.random.default_rng(job.seed)
    theta0 = random_pose(rng, plant.spec, margin=cfg.pose_margin)
    u = generate(
        job.kind,
        rng,
        job.n_step,
        plant.spec,
        theta0=theta0,
        omega_max=plant.omega_max,
        limit_margin=cfg.limit_margin,
        config=cfg.excitation,
    )
    out = plant.rollout(u[None], theta0=theta0[None])
    return {"theta0": theta0, "u": u, "theta": out["theta"][0], "omega": out["omega"][0]}


def _worker(args: tuple[EpisodeJob, SimulateConfig, MachineSpec]) -> dict[str, np.ndarray]:
    job, cfg, spec = args
    return simulate_episode(job, cfg, spec=spec)


def simulate_dataset(
    cfg: SimulateConfig,
    *,
    out: str | Path,
    workers: int | None = None,
    spec: MachineSpec = EXCAVATOR,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Simulate every episode of ``cfg`` and write the dataset folder ``out`` (atomically).

    Args:
        cfg: what to generate.
        out: dataset folder (replaced when complete).
        workers: processes (default ``cfg.workers``); the output does not depend on it.
        spec: machine spec (joint names must exist in the MJCF).
        extra: extra manifest entries (e.g. ``{"preset": "tiny"}``).

    Returns:
        ``out`` as a Path.
    """
    workers = cfg.workers if workers is None else int(workers)
    if workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
    spec = spec.with_rate(cfg.rate_hz) if spec.rate_hz != cfg.rate_hz else spec
    jobs = plan_episodes(cfg)
    n_samples = sum(j.n_step for j in jobs)
    log(
        f"simulate: {len(jobs)} episodes, {n_samples} samples at {cfg.rate_hz:g} Hz, {workers} worker(s)"
    )
    t0 = time.perf_counter()
    _plant(cfg, spec)  # fail early (bad MJCF / rate) in the parent, with a one-line error
    args = [(j, cfg, spec) for j in jobs]
    n_workers = min(workers, len(jobs))
    if n_workers <= 1:
        results = [_worker(a) for a in progress(args, total=len(args), desc="simulate")]
    else:
        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=n_workers, mp_context=ctx) as pool:
            results = list(progress(pool.map(_worker, args), total=len(args), desc="simulate"))
    cfg_dict = config_mod.to_dict(cfg)
    items = []
    for job, res in zip(jobs, results):
        n = job.n_step
        ep = Episode(
            spec=spec,
            time=np.arange(n) * spec.dt,
            u=res["u"],
            theta=res["theta"],
            omega=res["omega"],
            theta_true=res["theta"].copy() if cfg.record_truth else None,
            omega_true=res["omega"].copy() if cfg.record_truth else None,
            source=SOURCE,
            condition=cfg.condition,
            seed=job.seed,
            generator={
                "stage": "simulate",
                "signal": job.kind,
                "split": job.split,
                "index": job.index,
                "theta0": res["theta0"].tolist(),
                "config": cfg_dict,
            },
            name=job.name,
        )
        items.append((ep, job.split))
    path = write_dataset(out, items, config={"simulate": cfg_dict}, extra=extra)
    log(f"simulate: wrote {path} in {time.perf_counter() - t0:.1f} s")
    return path
