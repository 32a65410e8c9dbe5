"""MPPI control steps per second: planning through the surrogate vs through the plant model.

One MPPI control step samples K command sequences of N samples, rolls them out in ONE batched
call and updates the plan.  This benchmark tracks the start of the digging reference on
``ExcavatorMujoco-v0`` (the checkpoint's plant; hydraulic for the untrained one) with

- ``surrogate``: :class:`~excavator_surrogate.control.predict.SurrogatePredictor` (the
  surrogate engine synced to the plant's measured history), and
- ``oracle``: :class:`~excavator_surrogate.control.predict.PlantPredictor` (``mujoco.rollout``
  on a copy of the plant from its true state),

for the same K, N and number of control steps, on 1 and 2 CPUs each (the surrogate's
candidates split over that many processes, ``SurrogatePredictor(workers=...)``, one torch
thread each; ``mujoco.rollout`` on that many threads; the goals use each side's best), and
reports control steps/s and the ratio.  Without ``--ckpt`` the surrogate is an UNTRAINED LSTM of the paper's size (2 x 128,
W = 30): speed does not depend on training.  ``--report DIR`` adds the tracking-accuracy and
RL goals of an ``exsur control`` report folder (its metrics.json).  Ends with ONE JSON line.
Usage::

    python bench/control.py [--ckpt CKPT] [--samples 256] [--horizon 20] [--steps 20]
                            [--threads 1,2] [--report runs/quick/control]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import torch

from excavator_surrogate.control.mppi import MPPI, MPPIConfig
from excavator_surrogate.control.predict import PlantPredictor, SurrogatePredictor
from excavator_surrogate.control.reference import dig_reference
from excavator_surrogate.control.report import MPPI_SPEEDUP_MIN, STEPS_PER_S_MIN
from excavator_surrogate.control.tracking import MPPIController, track
from excavator_surrogate.env.mujoco_env import ExcavatorMujocoEnv
from excavator_surrogate.env.plants import checkpoint_plant
from excavator_surrogate.surrogate.checkpoint import load_checkpoint

sys.path.insert(0, str(Path(__file__).parent))
from env import paper_size_checkpoint

WARMUP = 3
"""Control steps excluded from the timing on both sides (first allocations and kernel choices;
a worker process's first calls)."""


def control_rate(kind: str, sur: object, cfg: MPPIConfig, n_control: int, threads: int) -> float:
    """Control steps per second of MPPI through ``kind``: the mean over ``n_control`` control
    steps after :data:`WARMUP` untimed ones."""
    theta_ref, _, _ = dig_reference(sur.spec)  # type: ignore[attr-defined]
    theta_ref = theta_ref[: (n_control + WARMUP) * cfg.replan + 1]
    # the plant the checkpoint was trained on (hydraulic if it does not record it)
    plant = checkpoint_plant(sur.spec, None, ckpt="--ckpt", default="hydraulic")  # type: ignore[attr-defined]
    env = ExcavatorMujocoEnv(plant=plant, spec=sur.spec)  # type: ignore[attr-defined,arg-type]
    torch.set_num_threads(1)
    if kind == "surrogate":
        pred = SurrogatePredictor(sur, n_batch=cfg.n_sample, workers=threads)  # type: ignore[arg-type]
    else:
        pred = PlantPredictor(env.plant, n_threads=threads)
    ctrl = MPPIController(MPPI(pred, cfg))
    try:
        track(env, ctrl, theta_ref)
    finally:
        if isinstance(pred, SurrogatePredictor):
            pred.close()
        env.close()
    times = ctrl.control_step_times()[WARMUP:]
    return len(times) / sum(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--ckpt", type=Path, default=None, help="surrogate checkpoint (default: untrained 2x128)"
    )
    ap.add_argument("--samples", type=int, default=256, help="K, candidates per control step")
    ap.add_argument("--horizon", type=int, default=20, help="N, horizon [samples]")
    ap.add_argument(
        "--steps", type=int, default=20, help="timed control steps per measurement (after 3)"
    )
    ap.add_argument("--threads", default="1,2", help="thread counts, comma-separated")
    ap.add_argument("--report", type=Path, default=None, help="an `exsur control` output folder")
    args = ap.parse_args()
    threads = [int(t) for t in str(args.threads).split(",")]
    cfg = MPPIConfig(n_sample=args.samples, n_horizon=args.horizon)
    res: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = args.ckpt or paper_size_checkpoint(Path(tmp) / "paper.pt", mode="stateful")
        sur = load_checkpoint(path)
        for kind in ("surrogate", "oracle"):
            for t in threads:
                key = f"{kind}_t{t}"
                res[key] = control_rate(kind, sur, cfg, args.steps, t)
                print(
                    f"MPPI K={cfg.n_sample} N={cfg.n_horizon} through the {kind:9s}, {t} CPU(s): "
                    f"{res[key]:8.2f} control steps/s ({1e3 / res[key]:8.1f} ms each)",
                    flush=True,
                )
            res[kind] = max(res[f"{kind}_t{t}"] for t in threads)
    speedup = res["surrogate"] / res["oracle"]
    print(f"ratio surrogate / oracle control steps per second: {speedup:.1f}x")
    goals: dict[str, bool] = {
        "surrogate_ge_10_control_steps_per_s": res["surrogate"] >= STEPS_PER_S_MIN,
        "surrogate_ge_10x_oracle": speedup >= MPPI_SPEEDUP_MIN,
    }
    if args.report is not None:
        m = json.loads((args.report / "metrics.json").read_text())
        for k, v in m["goals"].items():
            if k.startswith("rl_") or "rmse" in k:
                goals[k] = bool(v)
                print(f"from {args.report}: {k} = {v}")
    out = {
        "bench": "control",
        "unit": "MPPI control steps/s",
        "n_sample": cfg.n_sample,
        "n_horizon": cfg.n_horizon,
        "replan": cfg.replan,
        "n_control_steps": args.steps,
        "threads": threads,
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "model": str(args.ckpt) if args.ckpt else "lstm 2x128 untrained, W=30",
        **{k: round(v, 2) for k, v in res.items()},
        "ratios": {"surrogate_over_oracle": round(speedup, 2)},
        "goals": goals,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
