"""Throughput of the surrogate environments vs the MuJoCo plant, at the 20 Hz control rate.

Measures env-steps per second (one env-step = one 50 ms control step of one machine) for

- ``surrogate_vec_n{1,64,1024}``: :class:`SurrogateVectorEnv` on the stateful path (one torch
  batch, carried ``(h, c)``), full ``step()`` incl. action checks, guard and observations;
- ``surrogate_windowed_n{1,1024}``: the windowed fallback (re-runs the W = 30 window);
- ``surrogate_single``: ``ExcavatorSurrogate-v0`` (one env, Python loop);
- ``mujoco_env``: ``ExcavatorMujoco-v0`` (one env, Python loop, 25 physics steps per step);
- ``mujoco_rollout_2t``: :meth:`MujocoExcavator.rollout` (``mujoco.rollout``) on 2 threads;
- ``ensemble_n1024_plain`` / ``ensemble_n1024_uncertainty``: the vector env at 1024 envs on a
  merged 2-member ensemble of the same total size (2 x 64 members, calibrated, with a coverage
  record) without and with the uncertainty ``info`` (bands and OOD flags), measured in
  alternation, best of ``--repeats`` each; goal: the uncertainty costs <= 20 %;
- ``reset_*``: the vector env's resets at 1024 envs, from rest and from recorded starts (moments
  of 8 simulated plant episodes, ``recorded_starts=``): a reset of all envs, a masked reset of
  10 of them (medians of ``--reset-repeats``), and stepping with 50-step episodes whose
  autoresets draw recorded moments (in alternation with the envs from rest, best of
  ``--repeats`` each).  Goals: a masked reset of 10 envs costs <= 10 % of a
  reset of all 1024 (it draws, checks and warms up only the envs it resets), and recorded
  starts cost <= 20 % of the stepping rate from rest.

The benchmark model is an UNTRAINED LSTM of the paper's size (2 x 128, head 128, W = 30):
throughput does not depend on training.  Goals on the 2-core dev machine: >= 100k steps/s at
n_envs = 1024 and >= 1000 steps/s at n_envs = 1.  The vector env is measured with 1 and 2
torch threads: on a machine shared with other jobs, 2 OpenMP threads can be several times
SLOWER than 1 (threads wait for descheduled peers); the goals use the best.  Ends with ONE
JSON line.  Usage::

    python bench/env.py [--threads 1,2] [--seconds 1]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from excavator_surrogate.data.episode import Episode
from excavator_surrogate.env import ExcavatorMujocoEnv, ExcavatorSurrogateEnv, SurrogateVectorEnv
from excavator_surrogate.simulate.excitation import generate
from excavator_surrogate.simulate.plant import MujocoExcavator, PlantConfig
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.coverage import CoverageRecord, channel_names
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.features import Normalization
from excavator_surrogate.surrogate.model import ModelConfig, Surrogate, build_net

GOAL_N1024 = 100_000.0
GOAL_N1 = 1_000.0
GOAL_UNCERTAINTY_COST = 0.2
GOAL_MASKED_RESET_SHARE = 0.1
GOAL_RECORDED_STARTS_COST = 0.2


def untrained(*, mode: str, hidden: int = 128, seed: int = 0) -> Surrogate:
    """An untrained 2-layer LSTM (W = 30, head as wide as the layers) of the default excavator."""
    torch.manual_seed(seed)
    spec = EXCAVATOR
    cfg = ModelConfig(
        n_feature=spec.n_feature,
        n_joint=spec.n_joint,
        window=30,
        hidden=hidden,
        n_layer=2,
        head_hidden=hidden,
    )
    norm = Normalization.from_arrays(
        x_mean=np.zeros(spec.n_feature),
        x_std=np.ones(spec.n_feature),
        y_mean=np.zeros(spec.n_joint),
        y_std=np.full(spec.n_joint, 0.05),
        spec=spec,
    )
    return Surrogate(net=build_net(cfg).eval(), spec=spec, norm=norm, model_cfg=cfg, mode=mode)


def paper_size_checkpoint(path: Path, *, mode: str) -> Path:
    """An untrained 2 x 128 LSTM checkpoint (W = 30) for the default excavator."""
    return save_checkpoint(path, untrained(mode=mode))


def ensemble_checkpoint(path: Path) -> Path:
    """Two untrained 2 x 64 stateful members merged (2 x 128 in all), with a band calibration
    and a coverage record (the command box covers half the range: some steps flag)."""
    ens = merge([untrained(mode="stateful", hidden=64, seed=s) for s in range(2)])
    spec = EXCAVATOR
    n = spec.n_joint
    lo = np.concatenate([np.full(n, -500.0), np.full(n, -3.0), np.full(n, -2.0)])
    grid = np.ones((n, 10, 10), dtype=np.int64)
    grid[:, :3, :3] = 0
    rec = CoverageRecord(channel_names(spec), lo, -lo, grid, n_sample=1)
    k = np.ones((2, n))
    ens.metrics["coverage"] = rec.to_dict()
    ens.metrics["uncertainty"] = {
        "levels": [0.5, 0.9],
        "theta": k.tolist(),
        "omega": (2 * k).tolist(),
        "n_step": 1,
        "design": "shared",
    }
    return save_checkpoint(path, ens)


def rate(step: Callable[[int], None], n_per_call: int, seconds: float, *, warmup: int = 5) -> float:
    """Calls of ``step(i)`` for about ``seconds``; returns env-steps per second."""
    for i in range(warmup):
        step(i)
    n, t0 = 0, time.perf_counter()
    while True:
        step(n)
        n += 1
        dt = time.perf_counter() - t0
        if dt >= seconds and n >= 3:
            return n * n_per_call / dt


def bench_vector(
    ckpt: Path,
    n_envs: int,
    seconds: float,
    *,
    mode: str | None = None,
    uncertainty: bool | None = None,
) -> float:
    env = SurrogateVectorEnv(
        ckpt, n_envs, mode=mode, max_episode_steps=None, uncertainty=uncertainty
    )
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1000, 1000, (16, n_envs, EXCAVATOR.n_joint)).astype(np.float32)
    return rate(lambda i: env.step(actions[i % 16]), n_envs, seconds)


def bench_single(env: object, seconds: float) -> float:
    env.reset(seed=0)  # type: ignore[attr-defined]
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1000, 1000, (64, EXCAVATOR.n_joint)).astype(np.float32)
    return rate(lambda i: env.step(actions[i % 64]), 1, seconds)  # type: ignore[attr-defined]


def bench_rollout(n_threads: int, n_batch: int, n_step: int) -> float:
    plant = MujocoExcavator(PlantConfig(n_threads=n_threads))
    rng = np.random.default_rng(0)
    u = rng.uniform(-300, 300, (n_batch, n_step, EXCAVATOR.n_joint))
    theta0 = np.tile(plant.default_pose(), (n_batch, 1))
    plant.rollout(u[:, :3], theta0=theta0)  # thread pool start-up
    t0 = time.perf_counter()
    plant.rollout(u, theta0=theta0)
    dt = time.perf_counter() - t0
    plant.close()
    return n_batch * (n_step - 1) / dt


def plant_episodes(n_episode: int = 8, n_step: int = 400) -> list[Episode]:
    """Plant episodes under the ``steps`` excitation (held random commands, kept off the end
    stops), to draw recorded starts from."""
    plant = MujocoExcavator(PlantConfig(n_threads=2))
    rng = np.random.default_rng(1)
    theta0 = np.tile(plant.default_pose(), (n_episode, 1))
    u = np.stack([generate("steps", rng, n_step, EXCAVATOR, theta0=th) for th in theta0])
    out = plant.rollout(u, theta0=theta0)
    plant.close()
    t = np.arange(n_step) * EXCAVATOR.dt
    return [
        Episode(EXCAVATOR, t, u[b], out["theta"][b], out["omega"][b], name=f"plant{b}")
        for b in range(n_episode)
    ]


def median_ms(call: Callable[[int], None], repeats: int) -> float:
    """Median wall time of ``call(i)`` over ``repeats`` calls (after one warm-up) [ms]."""
    call(-1)
    ts = []
    for i in range(repeats):
        t0 = time.perf_counter()
        call(i)
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)) * 1e3


def bench_resets(
    ckpt: Path, starts: list[Episode] | None, *, n_envs: int, repeats: int
) -> tuple[float, float, SurrogateVectorEnv]:
    """The vector env's reset of all ``n_envs`` and masked reset of 10 [ms] (medians), from
    rest or from recorded ``starts``, and the env (50-step episodes) to step."""
    env = SurrogateVectorEnv(ckpt, n_envs, max_episode_steps=50, recorded_starts=starts)
    env.reset(seed=0)
    full = median_ms(lambda i: env.reset(seed=i + 1), repeats)
    rng = np.random.default_rng(0)
    masks = np.zeros((repeats + 1, n_envs), dtype=bool)
    for m in masks:
        m[rng.choice(n_envs, 10, replace=False)] = True
    masked = median_ms(lambda i: env.reset(options={"reset_mask": masks[i]}), repeats)
    env.reset(seed=0)
    return full, masked, env


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--threads",
        default="1,2",
        help="torch thread counts to measure the vector env with, comma-separated (default 1,2)",
    )
    ap.add_argument("--rollout-threads", type=int, default=2, help="mujoco.rollout threads")
    ap.add_argument("--seconds", type=float, default=1.0, help="time per measurement [s]")
    ap.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="alternating measurements with and without the uncertainty info (default 3)",
    )
    ap.add_argument(
        "--reset-repeats", type=int, default=30, help="resets timed per median (default 30)"
    )
    args = ap.parse_args()
    threads = [int(t) for t in str(args.threads).split(",")]
    res: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        stateful = paper_size_checkpoint(Path(tmp) / "stateful.pt", mode="stateful")
        windowed = paper_size_checkpoint(Path(tmp) / "windowed.pt", mode="windowed")
        for t in threads:
            torch.set_num_threads(t)
            for n in (1, 64, 1024):
                key = f"surrogate_vec_n{n}_t{t}"
                res[key] = bench_vector(stateful, n, args.seconds)
                print(
                    f"surrogate vector env, stateful, n_envs={n:5d}, {t} thread(s): {res[key]:12,.0f} steps/s",
                    flush=True,
                )
        for n in (1, 64, 1024):  # best over thread counts (the machine is shared)
            res[f"surrogate_vec_n{n}"] = max(res[f"surrogate_vec_n{n}_t{t}"] for t in threads)
        torch.set_num_threads(min(threads))
        for n in (1, 1024):
            key = f"surrogate_windowed_n{n}"
            res[key] = bench_vector(windowed, n, args.seconds, mode="windowed")
            print(
                f"surrogate vector env, windowed, n_envs={n:5d}, {min(threads)} thread(s): {res[key]:12,.0f} steps/s",
                flush=True,
            )
        ensemble = ensemble_checkpoint(Path(tmp) / "ensemble.pt")
        plain, unc = [], []
        for _ in range(max(1, args.repeats)):  # alternate: the machine's load hits both alike
            plain.append(bench_vector(ensemble, 1024, args.seconds, uncertainty=False))
            unc.append(bench_vector(ensemble, 1024, args.seconds, uncertainty=True))
        res["ensemble_n1024_plain"], res["ensemble_n1024_uncertainty"] = max(plain), max(unc)
        print(
            f"2-member ensemble, n_envs= 1024, {min(threads)} thread(s): "
            f"{res['ensemble_n1024_plain']:12,.0f} steps/s plain, "
            f"{res['ensemble_n1024_uncertainty']:12,.0f} with uncertainty info",
            flush=True,
        )
        starts = plant_episodes()
        envs = {}
        for name, source in (("rest", None), ("recorded", starts)):
            full, masked, envs[name] = bench_resets(
                stateful, source, n_envs=1024, repeats=max(3, args.reset_repeats)
            )
            res[f"reset_full_{name}_ms"], res[f"reset_masked10_{name}_ms"] = full, masked
        actions = np.random.default_rng(0).uniform(-1000, 1000, (16, 1024, EXCAVATOR.n_joint))
        actions = actions.astype(np.float32)
        steps: dict[str, list[float]] = {"rest": [], "recorded": []}
        for _ in range(max(1, args.repeats)):  # alternate: the machine's load hits both alike
            for name, env in envs.items():
                steps[name].append(
                    rate(lambda i, e=env: e.step(actions[i % 16]), 1024, args.seconds)
                )
        res["reset_steps_rest"], res["reset_steps_recorded"] = (max(steps[k]) for k in steps)
        print(
            f"resets of 1024 envs, {min(threads)} thread(s): all "
            f"{res['reset_full_rest_ms']:.1f} ms from rest, "
            f"{res['reset_full_recorded_ms']:.1f} ms recorded; 10 masked "
            f"{res['reset_masked10_rest_ms']:.2f} / {res['reset_masked10_recorded_ms']:.2f} ms; "
            f"50-step episodes {res['reset_steps_rest']:,.0f} / {res['reset_steps_recorded']:,.0f} steps/s",
            flush=True,
        )
        res["surrogate_single"] = bench_single(ExcavatorSurrogateEnv(stateful), args.seconds)
        print(
            f"ExcavatorSurrogate-v0, single env loop:               {res['surrogate_single']:12,.0f} steps/s",
            flush=True,
        )
    res["mujoco_env"] = bench_single(ExcavatorMujocoEnv(), args.seconds)
    print(
        f"ExcavatorMujoco-v0, single env loop:                  {res['mujoco_env']:12,.0f} steps/s",
        flush=True,
    )
    rt = args.rollout_threads
    res[f"mujoco_rollout_{rt}t"] = bench_rollout(rt, 256, 101)
    print(
        f"mujoco.rollout, {rt} threads, 256 envs:                 {res[f'mujoco_rollout_{rt}t']:12,.0f} steps/s",
        flush=True,
    )
    ratios = {
        "vec1024_over_mujoco_rollout": res["surrogate_vec_n1024"] / res[f"mujoco_rollout_{rt}t"],
        "vec1024_over_mujoco_env": res["surrogate_vec_n1024"] / res["mujoco_env"],
        "vec1_over_mujoco_env": res["surrogate_vec_n1"] / res["mujoco_env"],
        "stateful_over_windowed_n1024": res["surrogate_vec_n1024"]
        / res["surrogate_windowed_n1024"],
        "uncertainty_over_plain_n1024": res["ensemble_n1024_uncertainty"]
        / res["ensemble_n1024_plain"],
        "masked10_over_full_reset_recorded": res["reset_masked10_recorded_ms"]
        / res["reset_full_recorded_ms"],
        "recorded_over_rest_steps": res["reset_steps_recorded"] / res["reset_steps_rest"],
    }
    for k, v in ratios.items():
        print(f"ratio {k}: {v:.2f}x")
    goals = {
        "n1024_ge_100k": res["surrogate_vec_n1024"] >= GOAL_N1024,
        "n1_ge_1000": res["surrogate_vec_n1"] >= GOAL_N1,
        "uncertainty_cost_le_20pct": ratios["uncertainty_over_plain_n1024"]
        >= 1.0 - GOAL_UNCERTAINTY_COST,
        "masked_reset_le_10pct_of_full": ratios["masked10_over_full_reset_recorded"]
        <= GOAL_MASKED_RESET_SHARE,
        "recorded_starts_cost_le_20pct": ratios["recorded_over_rest_steps"]
        >= 1.0 - GOAL_RECORDED_STARTS_COST,
    }
    out = {
        "bench": "env",
        "unit": "env-steps/s at 20 Hz",
        "torch_threads": threads,
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "model": "lstm 2x128 untrained, W=30",
        **{k: round(v, 2) for k, v in res.items()},
        "ratios": {k: round(v, 3) for k, v in ratios.items()},
        "goals": goals,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
