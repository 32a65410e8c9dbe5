"""Benchmark: windowed (paper) vs stateful (TBPTT) training on the same data, in one run.

Reports per mode: wall time per training epoch, time to reach a target validation free-run
error, best validation error and the final CBE metrics (min R^2 over joints for theta and
omega) on the test split; then the stateful/windowed ratios.  The last line is one JSON object.

Usage::

    python bench/train.py                            # synthetic 4-joint data, 120 s budget per mode
    python bench/train.py --dataset runs/quick/data --preset quick --budget 150
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch

from excavator_surrogate.config import load_preset
from excavator_surrogate.data import load_dataset
from excavator_surrogate.evaluate import evaluate_models, min_r2
from excavator_surrogate.surrogate import load_checkpoint, read_checkpoint
from excavator_surrogate.surrogate.synthetic import synthetic_spec, write_synthetic_dataset
from excavator_surrogate.training import TrainConfig, train


def _parse() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dataset", type=Path, default=None, help="dataset folder (default: synthetic)")
    p.add_argument("--preset", default=None, help="preset whose [train] table is the base config")
    p.add_argument("--out", type=Path, default=None, help="work folder (default: a temp folder)")
    p.add_argument(
        "--budget", type=float, default=120.0, help="training wall-time budget per mode [s]"
    )
    p.add_argument("--epochs", type=int, default=200, help="max epochs per mode")
    p.add_argument(
        "--target", type=float, default=0.15, help="target validation error (NRMSE of theta)"
    )
    p.add_argument("--hidden", type=int, default=None, help="override hidden width")
    p.add_argument("--window", type=int, default=None, help="override window W")
    p.add_argument("--n-joint", type=int, default=4, help="synthetic: joints")
    p.add_argument("--n-train", type=int, default=8, help="synthetic: training episodes")
    p.add_argument(
        "--n-step", type=int, default=1200, help="synthetic: samples per train/val episode"
    )
    p.add_argument(
        "--test-steps", type=int, default=1800, help="synthetic: samples of the step test"
    )
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--modes", default="windowed,stateful", help="comma-separated modes to run")
    return p.parse_args()


def main() -> int:
    args = _parse()
    torch.set_num_threads(args.threads)
    work = args.out or Path(tempfile.mkdtemp(prefix="exsur-bench-"))
    if args.dataset is None:
        t0 = time.monotonic()
        args.dataset = write_synthetic_dataset(
            work / "data",
            synthetic_spec(args.n_joint),
            n_train=args.n_train,
            n_val=1,
            n_test=1,
            n_step=args.n_step,
            test_steps=args.test_steps,
            noise=0.001,
        )
        print(
            f"synthetic dataset in {time.monotonic() - t0:.1f} s: {args.dataset}", file=sys.stderr
        )
    ds = load_dataset(args.dataset)
    base = TrainConfig.from_preset(load_preset(args.preset)) if args.preset else TrainConfig()
    over = {
        "epochs": args.epochs,
        "max_train_seconds": args.budget,
        "tensorboard": False,
        "patience": 10**6,
        "num_threads": args.threads,
    }
    if args.hidden:
        over |= {"hidden": args.hidden, "head_hidden": args.hidden}
    if args.window:
        over["window"] = args.window
    results: dict[str, dict] = {}
    for mode in args.modes.split(","):
        cfg = replace(base, mode=mode, **over)
        best = train(cfg, ds, out=work / mode, show_progress=False)
        hist = read_checkpoint(work / mode / "last.pt")["history"]
        sur = load_checkpoint(best)
        metrics, _ = evaluate_models({mode: sur}, ds.test)
        m = metrics[mode]
        reach = next((h["time_s"] for h in hist if h["val_error"] <= args.target), math.inf)
        full = [h["epoch_s"] for h in hist if h["n_sample"] > 0]
        results[mode] = {
            "epochs": len(hist),
            "epoch_s": sum(full) / len(full),
            "val_s": sum(h["val_s"] for h in hist) / len(hist),
            "time_to_target_s": reach,
            "best_val_error": min(h["val_error"] for h in hist),
            "theta_r2_min": min_r2(m, "theta"),
            "omega_r2_min": min_r2(m, "omega"),
            "theta_r2": {j: v["r2"] for j, v in m["theta"].items()},
            "omega_r2": {j: v["r2"] for j, v in m["omega"].items()},
        }
    print(
        f"\n{'mode':>9} | epochs | s/epoch | val s | t(val<={args.target}) | best val | min θ R² | min ω R²"
    )
    for mode, r in results.items():
        print(
            f"{mode:>9} | {r['epochs']:6d} | {r['epoch_s']:7.2f} | {r['val_s']:5.2f} | "
            f"{r['time_to_target_s']:12.1f} | {r['best_val_error']:8.4f} | {r['theta_r2_min']:8.4f} | "
            f"{r['omega_r2_min']:8.4f}"
        )
    ratios = {}
    if {"windowed", "stateful"} <= set(results):
        w, s = results["windowed"], results["stateful"]
        ratios = {
            "epoch_time_windowed_over_stateful": w["epoch_s"] / s["epoch_s"],
            "time_to_target_windowed_over_stateful": (
                w["time_to_target_s"] / s["time_to_target_s"]
                if math.isfinite(s["time_to_target_s"])
                else None
            ),
        }
        print(
            "ratios (windowed / stateful):",
            {k: (round(v, 2) if v else v) for k, v in ratios.items()},
        )

    def clean(o):  # JSON has no inf
        if isinstance(o, float) and not math.isfinite(o):
            return None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        return o

    print(
        json.dumps(
            clean(
                {
                    "bench": "train",
                    "dataset": str(args.dataset),
                    "budget_s": args.budget,
                    "target": args.target,
                    "results": results,
                    "ratios": ratios,
                }
            )
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
