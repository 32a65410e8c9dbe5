"""Throughput of the Stage I MuJoCo plant: Python loop vs batched ``mujoco.rollout``.

Prints control steps (20 Hz) per second and multiples of real time for

- ``loop``: :meth:`MujocoExcavator.step` one control step at a time (reference path),
- ``rollout_1t``: :meth:`MujocoExcavator.rollout`, ``n_batch`` episodes on 1 thread,
- ``rollout_Nt``: the same on ``--threads`` threads,

and ends with ONE JSON line of the figures, with a ``goals`` object of booleans: the loop and
the batched rollouts give the same bits, the batched rollout on ``--threads`` threads is at
least 1.5x the loop (``mujoco.rollout`` is how ``exsur simulate`` makes datasets), and every
path runs at least 100x real time.  Usage::

    python bench/simulate.py [--batch 64] [--steps 400] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from excavator_surrogate.simulate.excitation import generate
from excavator_surrogate.simulate.generate import random_pose
from excavator_surrogate.simulate.plant import MujocoExcavator, PlantConfig

GOAL_BATCHED_OVER_LOOP = 1.5
"""The batched rollout on ``--threads`` (default 2) threads against the Python loop."""
GOAL_X_REALTIME = 100.0
"""Every path, in multiples of real time (a 10-minute dataset in seconds)."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=64, help="episodes in the batched rollout")
    ap.add_argument("--steps", type=int, default=400, help="control steps per episode")
    ap.add_argument("--threads", type=int, default=2, help="threads of the multi-threaded rollout")
    ap.add_argument(
        "--loop-episodes", type=int, default=4, help="episodes run through the Python loop"
    )
    args = ap.parse_args()

    rng = np.random.default_rng(0)
    plant = MujocoExcavator()
    spec = plant.spec
    theta0 = np.stack([random_pose(rng, spec) for _ in range(args.batch)])
    u = np.stack(
        [
            generate(
                "multisine", rng, args.steps, spec, theta0=theta0[b], omega_max=plant.omega_max
            )
            for b in range(args.batch)
        ]
    )
    per_s = 1.0 / spec.dt
    res: dict[str, float] = {}

    n_loop = min(args.loop_episodes, args.batch)
    t = time.perf_counter()
    loop = plant.simulate(u[:n_loop], theta0=theta0[:n_loop])
    res["loop"] = n_loop * (args.steps - 1) / (time.perf_counter() - t)

    t = time.perf_counter()
    one = plant.rollout(u, theta0=theta0)
    res["rollout_1t"] = args.batch * (args.steps - 1) / (time.perf_counter() - t)

    multi = MujocoExcavator(PlantConfig(n_threads=args.threads))
    multi.rollout(u[:2], theta0=theta0[:2])  # start the pool
    t = time.perf_counter()
    many = multi.rollout(u, theta0=theta0)
    res[f"rollout_{args.threads}t"] = args.batch * (args.steps - 1) / (time.perf_counter() - t)
    multi.close()

    same = bool(
        np.array_equal(loop["theta"], one["theta"][:n_loop])
        and np.array_equal(one["theta"], many["theta"])
    )
    print(
        f"episodes {args.batch} x {args.steps} control steps at {1 / spec.dt:g} Hz "
        f"({plant.substeps} physics steps each); loop == rollout: {same}"
    )
    for name, sps in res.items():
        print(f"  {name:<12s} {sps:12,.0f} control steps/s = {sps / per_s:8,.0f} x real time")
    speedup = res[f"rollout_{args.threads}t"] / res["loop"]
    print(f"  batched ({args.threads} threads) / loop: {speedup:.1f}x")
    goals = {
        "loop_equals_rollout": same,
        f"batched_ge_{GOAL_BATCHED_OVER_LOOP:g}x_loop": bool(speedup >= GOAL_BATCHED_OVER_LOOP),
        f"every_path_ge_{GOAL_X_REALTIME:g}x_realtime": bool(
            min(res.values()) / per_s >= GOAL_X_REALTIME
        ),
    }
    print(
        json.dumps(
            {
                "bench": "simulate",
                "n_batch": args.batch,
                "n_step": args.steps,
                "threads": args.threads,
                "steps_per_s": {k: round(v, 1) for k, v in res.items()},
                "x_realtime": {k: round(v / per_s, 1) for k, v in res.items()},
                "speedup_batched_vs_loop": round(speedup, 2),
                "identical": same,
                "goals": goals,
            }
        )
    )


if __name__ == "__main__":
    main()
