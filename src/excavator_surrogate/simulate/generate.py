"""Generate simulated datasets: excitation -> MuJoCo plant -> (sensors) -> episode files.

:func:`simulate_dataset` writes a dataset folder (see :mod:`excavator_surrogate.data`) with
``train``, ``val`` and ``test`` episodes.  Episodes are simulated in parallel processes;
the output is identical for a given seed whatever the number of workers, because every
episode draws from its own seed: ``SeedSequence(seed)`` spawns one child per split (train,
val, test) and each split's child spawns one seed per episode, so e.g. the test episodes do
not change when ``n_train`` changes.

Plants (``SimulateConfig.plant``): ``ideal`` (Stage I, source ``mujoco-ideal``) or
``hydraulic`` (Stage II stand-in, :mod:`.hydraulics`, source ``mujoco-hydraulic``).  With
``soil.enabled`` (compound operation, :mod:`.soil`) or a closed-loop signal (``dig_cycle``)
an episode runs in the Python loop (force hooks, operator feedback); otherwise in the
batched ``mujoco.rollout``.  With ``sensors = true`` the sensor model
(:mod:`.sensors`) turns the true angles/velocities into measured ones; the truth is kept in
``theta_<j>_true`` / ``omega_<j>_true``.  Per-episode random streams: ``default_rng(seed)``
(pose, commands, operator), ``default_rng([seed, 1])`` (sensor faults),
``default_rng([seed, 2])`` (plant variation: initial oil temperature), and per day of
``days`` ``default_rng([root seed, 3, day])`` (the day's slow-down).
"""

from __future__ import annotations

import dataclasses
import logging
import multiprocessing as mp
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from .. import config as config_mod
from .. import numerics
from ..data import Episode, write_dataset
from ..data.timesplit import split_in_time
from ..errors import ConfigError, DataError, need_path
from ..io_utils import check_replaceable, init_worker_logging, progress, worker_log_config
from ..orphans import die_with_parent, parent_args
from ..spec import EXCAVATOR, MachineSpec
from .config import INPUTS, SimulateConfig
from .excitation import (
    CLOSED_LOOP,
    DigOperator,
    NominalModel,
    generate,
)
from .hydraulics import HydraulicTransform
from .plant import MujocoExcavator
from .relief import ReliefAntiWindup
from .sensors import apply_sensors_episode
from .session import SessionOperator
from .soil import ChainHook, SoilHook

_log = logging.getLogger(__name__)


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
    day: int | None = None
    """The episode's day in ``SimulateConfig.days`` (None: no days)."""

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
    day_of = [d for d, n in enumerate(cfg.days) for _ in range(n)]
    for (split, n, n_step, kinds), seq in zip(plan, split_seqs):
        for i, child in enumerate(seq.spawn(n)):
            seed = int(child.generate_state(1, dtype=np.uint32)[0])
            day = day_of[len(jobs)] if day_of else None
            jobs.append(EpisodeJob(split, i, kinds[i % len(kinds)], n_step, seed, day))
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


def build_plant(cfg: SimulateConfig, spec: MachineSpec, *, loop: bool = False) -> MujocoExcavator:
    """The plant of ``cfg``: ideal or hydraulic; with ``loop`` the Python-loop variant with
    force hooks (relief anti-windup if force-limited, soil if ``cfg.soil.enabled``)."""
    transform = HydraulicTransform(cfg.hydraulics, spec=spec) if cfg.plant == "hydraulic" else None
    plant = MujocoExcavator(cfg.plant_config(), spec=spec, command_transform=transform)
    if loop:
        hooks: list[Any] = []
        if bool(np.any(plant.model.actuator_forcelimited)):
            hooks.append(ReliefAntiWindup(spec=plant.spec))
        if cfg.soil.enabled:
            hooks.append(SoilHook(cfg.soil))
        if hooks:
            plant.force_hook = ChainHook(*hooks)
    return plant


def _plant(cfg: SimulateConfig, spec: MachineSpec, *, loop: bool = False) -> MujocoExcavator:
    """One cached plant per process and configuration."""
    key = (cfg.xml, cfg.rate_hz, cfg.delay_s, cfg.plant, cfg.hydraulics, cfg.soil, loop, spec)
    if key not in _PLANTS:
        _PLANTS[key] = build_plant(cfg, spec, loop=loop)
    return _PLANTS[key]


def _soil_hook(plant: MujocoExcavator) -> SoilHook | None:
    hook = plant.force_hook
    if isinstance(hook, ChainHook):
        return next((h for h in hook.hooks if isinstance(h, SoilHook)), None)
    return hook if isinstance(hook, SoilHook) else None


def _run_loop(
    plant: MujocoExcavator,
    theta0: np.ndarray,
    n_step: int,
    *,
    u: np.ndarray | None = None,
    operator: DigOperator | SessionOperator | None = None,
    tip_site: str = "tip",
) -> dict[str, Any]:
    """Python-loop episode with open-loop commands ``u: (n_step, n_joint)`` or a closed-loop
    ``operator``.  Returns ``u``, ``theta``, ``omega`` (n_step, n_joint) and ``info``."""
    n = plant.n_joint
    theta = np.empty((n_step, n))
    omega = np.empty((n_step, n))
    cmds = np.empty((n_step, n))
    theta[0], omega[0] = plant.reset(theta0=theta0)
    soil = _soil_hook(plant)
    tip = mujoco.mj_name2id(plant.model, mujoco.mjtObj.mjOBJ_SITE, tip_site)
    if operator is not None:
        if tip < 0:
            raise ConfigError(
                f"closed-loop operator needs an MJCF site '{tip_site}' at the bucket tip"
            )
        operator.reset(theta0)
    cap = soil.config.capacity_m3 if soil is not None else 1.0
    payload = np.zeros(n_step)
    throttle = np.ones(n_step)
    for k in range(n_step):
        if operator is not None:
            fill = soil.volume / cap if soil is not None and cap > 0 else 0.0
            cmds[k] = operator(
                theta[k], omega[k], tip=plant.data.site_xpos[tip], payload_fraction=fill
            )
        else:
            assert u is not None
            cmds[k] = u[k]
        if soil is not None:
            payload[k] = soil.payload_kg
        if isinstance(operator, SessionOperator):  # the engine throttle scales the pump
            throttle[k] = operator.throttle
            if isinstance(plant.transform, HydraulicTransform):
                plant.transform.pump_scale = throttle[k]
        if k < n_step - 1:
            theta[k + 1], omega[k + 1] = plant.step(cmds[k])
    info: dict[str, Any] = {}
    if soil is not None:
        st = dict(soil.stats)
        info["compound"] = {
            **{k: round(float(v), 4) for k, v in st.items()},
            "mean_payload_kg": round(float(payload.mean()), 2),
            "below_ground_fraction": round(st["below_ground_s"] / max(n_step * plant.dt, 1e-9), 4),
        }
    if operator is not None:
        info["operator"] = {
            "cycles": operator.cycles,
            "phases": [[k, ph] for k, ph in operator.phase_log],
        }
    return {
        "u": cmds,
        "theta": theta,
        "omega": omega,
        "info": info,
        "inputs": {"throttle": throttle},
    }


def simulate_episode(
    job: EpisodeJob, cfg: SimulateConfig, *, spec: MachineSpec = EXCAVATOR
) -> dict[str, Any]:
    """Simulate one planned episode (true states; sensors are applied by the caller).

    Returns:
        ``theta0`` (n_joint,), ``u``, ``theta``, ``omega`` (n_step, n_joint) and ``info``
        (JSON-able plant facts: drift amplitude, compound statistics, operator phases).
    """
    closed = job.kind in CLOSED_LOOP
    loop = closed or cfg.soil.enabled
    plant = _plant(cfg, spec, loop=loop)
    rng = np.random.default_rng(job.seed)
    theta0 = random_pose(rng, plant.spec, margin=cfg.pose_margin)
    if cfg.soil.enabled:  # start with the bucket above ground
        for _ in range(200):
            if plant.site_position(theta0, cfg.soil.tip_site)[2] > cfg.soil.ground_z + 0.5:
                break
            theta0 = random_pose(rng, plant.spec, margin=cfg.pose_margin)
    info: dict[str, Any] = {}
    velocity_map: NominalModel | None = None
    if isinstance(plant.transform, HydraulicTransform):
        hcfg = cfg.hydraulics
        if hcfg.drift:  # initial oil temperature varies between episodes
            prng = np.random.default_rng([job.seed, 2])
            amp = float(prng.uniform(0.0, hcfg.drift_amplitude))
            hcfg = dataclasses.replace(hcfg, drift_amplitude=amp)
            info["drift_amplitude"] = round(amp, 6)
        if job.day is not None:  # the day's speed, shared by the day's sessions
            drng = np.random.default_rng([cfg.seed, 3, job.day])
            slow = float(drng.uniform(0.0, hcfg.day_slowdown))
            hcfg = dataclasses.replace(hcfg, day_slowdown=slow)
            info["day"], info["day_slowdown"] = job.day, round(slow, 6)
        plant.transform = HydraulicTransform(hcfg, spec=plant.spec)  # (the plant is cached)
        velocity_map = plant.transform.nominal_model(omega_max=plant.omega_max)

    if closed:
        operator: DigOperator | SessionOperator
        if job.kind == "dig_session":
            operator = SessionOperator(
                plant.spec,
                rng=rng,
                params=cfg.excitation.dig_session,
                dig=cfg.excitation.dig_cycle,
                ground_z=cfg.soil.ground_z,
            )
        else:
            operator = DigOperator(
                plant.spec, rng=rng, params=cfg.excitation.dig_cycle, ground_z=cfg.soil.ground_z
            )
        res = _run_loop(plant, theta0, job.n_step, operator=operator, tip_site=cfg.soil.tip_site)
        info.update(res["info"])
        return {
            "theta0": theta0,
            "u": res["u"],
            "theta": res["theta"],
            "omega": res["omega"],
            "info": info,
            "inputs": res["inputs"],
        }
    u = generate(
        job.kind,
        rng,
        job.n_step,
        plant.spec,
        theta0=theta0,
        omega_max=plant.omega_max,
        limit_margin=cfg.limit_margin,
        config=cfg.excitation,
        velocity_map=velocity_map,
    )
    if loop:
        res = _run_loop(plant, theta0, job.n_step, u=u, tip_site=cfg.soil.tip_site)
        info.update(res["info"])
        return {
            "theta0": theta0,
            "u": u,
            "theta": res["theta"],
            "omega": res["omega"],
            "info": info,
        }
    out = plant.rollout(u[None], theta0=theta0[None])
    return {
        "theta0": theta0,
        "u": u,
        "theta": out["theta"][0],
        "omega": out["omega"][0],
        "info": info,
    }


def _init_worker(log_config: Any, parent: tuple[int, bool]) -> None:
    """Simulation pool initializer: log at the parent's level, and exit when it dies."""
    init_worker_logging(log_config)
    die_with_parent(*parent)


def _worker(args: tuple[EpisodeJob, SimulateConfig, MachineSpec]) -> dict[str, Any]:
    job, cfg, spec = args
    return simulate_episode(job, cfg, spec=spec)


def simulated_data_error(err: DataError, cfg: SimulateConfig) -> DataError:
    """``err``, an episode the simulation produced that breaks the episode contract, reworded
    for ``exsur simulate``: it names the episode (not the temporary file it was being written
    to) and the ``[simulate]`` settings to change, not the import's advice for a raw log.
    Errors about anything other than an episode file pass through unchanged."""
    path = Path(str(err.path)) if err.path is not None else None
    if path is None or path.suffix != ".parquet":
        return err
    return DataError(
        f"simulated episode '{path.stem}'",
        err.problem,
        column=err.column,
        row=err.row,
        fix=f"the [simulate] settings (rate_hz = {cfg.rate_hz:g} Hz, plant = '{cfg.plant}') "
        "drive the simulator outside its working range: change them (exsur config show "
        "PRESET --section simulate lists them)",
    )


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

    Raises:
        ConfigError: ``cfg`` not a :class:`SimulateConfig`, ``out`` not a path or a folder
            exsur did not write (before anything is simulated), a bad
            option, or ``EXSUR_NUMERICS=portable`` that did not reach NumPy
            or OpenBLAS (NumPy was imported before the package).
    """
    config_mod.need_config(cfg, SimulateConfig)
    out = need_path(out, "out")  # before the simulation, not when the dataset is written
    check_replaceable(out, "dataset")  # the write's own rule: a user's folder, refused up front
    workers = cfg.workers if workers is None else int(workers)
    if workers < 1:
        raise ConfigError(f"workers must be >= 1, got {workers}")
    numerics.check_numpy()  # portable: NumPy's AVX2 loops and OpenBLAS's Haswell kernels
    spec = spec.with_rate(cfg.rate_hz) if spec.rate_hz != cfg.rate_hz else spec
    plant_spec = spec
    if cfg.inputs:
        spec = dataclasses.replace(spec, inputs=tuple(INPUTS[n] for n in cfg.inputs))
    jobs = plan_episodes(cfg)
    n_samples = sum(j.n_step for j in jobs)
    _log.info(
        f"simulate: {len(jobs)} episodes, {n_samples} samples at {cfg.rate_hz:g} Hz, "
        f"{min(workers, len(jobs))} worker(s)"  # at most one per episode
    )
    t0 = time.perf_counter()
    _plant(cfg, plant_spec)  # fail early (bad MJCF / rate / hydraulics) in the parent, one line
    args = [(j, cfg, plant_spec) for j in jobs]
    n_workers = min(workers, len(jobs))
    if n_workers <= 1:
        results = [_worker(a) for a in progress(args, total=len(args), desc="simulate")]
    else:
        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(
            max_workers=n_workers,
            mp_context=ctx,
            initializer=_init_worker,  # this process's log level; die with this process
            initargs=(worker_log_config(), parent_args()),
        ) as pool:
            results = list(progress(pool.map(_worker, args), total=len(args), desc="simulate"))
    cfg_dict = config_mod.to_dict(cfg)
    items = []
    for job, res in zip(jobs, results):
        n = job.n_step
        u = res["u"]
        if cfg.inputs:  # exogenous inputs after the joints' commands (1 = full throttle)
            ins = res.get("inputs", {})
            cols = [np.asarray(ins.get(name, np.ones(n)), dtype=np.float64) for name in cfg.inputs]
            u = np.concatenate([u, np.stack(cols, axis=1)], axis=1)
        ep = Episode(
            spec=spec,
            time=np.arange(n) * spec.dt,
            u=u,
            theta=res["theta"],
            omega=res["omega"],
            theta_true=res["theta"].copy() if cfg.record_truth else None,
            omega_true=res["omega"].copy() if cfg.record_truth else None,
            source=cfg.source,
            condition=cfg.condition,
            seed=job.seed,
            generator={
                "stage": "simulate",
                "signal": job.kind,
                "split": job.split,
                "index": job.index,
                "theta0": res["theta0"].tolist(),
                "config": cfg_dict,
                **({"plant": res["info"]} if res.get("info") else {}),
            },
            name=job.name,
        )
        if cfg.sensors:
            ep = apply_sensors_episode(
                ep, config=cfg.sensor, rng=np.random.default_rng([job.seed, 1])
            )
        if job.split == "train" and (cfg.val_s > 0 or cfg.test_s > 0):
            items += split_in_time(ep, val_s=cfg.val_s, test_s=cfg.test_s)
        else:
            items.append((ep, job.split))
    # the computer's numerics and library versions: a closed-loop operator grows a last-bit
    # difference between two computers into another log (docs/real.md)
    extra = {"environment": numerics.environment(), **(extra or {})}
    try:
        path = write_dataset(out, items, config={"simulate": cfg_dict}, extra=extra)
    except DataError as e:
        raise simulated_data_error(e, cfg) from e
    _log.info(f"simulate: wrote {path} in {time.perf_counter() - t0:.1f} s")
    return path
