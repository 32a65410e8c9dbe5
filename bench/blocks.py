"""Free runs of merged seed ensembles: the merged network against its member blocks.

A batched free run (:func:`~excavator_surrogate.surrogate.rollout.rollout`, what validation,
the recipe's choices and evaluation run) steps a merged ensemble as its member blocks
(:mod:`excavator_surrogate.surrogate.blocks`) from :data:`MIN_SPLIT_WIDTH` merged units on.
This times the same free run both ways, side by side in one process, for untrained
members (2 x ``h`` LSTM, head ``h``): ``merged`` is the merged network's own cells (its
merge record removed, so it is not split), ``blocks`` the default.  Ratios are the median
over ``--repeats`` pairs of runs (the order swapped every pair) of ``blocks / merged`` per
step, one torch thread (a member's setting).  The unsplit rows run the same code twice:
their ratio is the measurement's noise.  Models are untrained: speed does not depend on
training.

Goals: the recipe's ensembles (4 and 6 members of 128) at most 0.9x the merged time at batch
2 and 0.5x at batch 13, the noise within 10 %, and the two runs' angles within 1e-4 rad.  Ends with ONE JSON
line.  Usage::

    python bench/blocks.py [--steps 300] [--repeats 8]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from excavator_surrogate.surrogate.blocks import MIN_SPLIT_WIDTH
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.model import Surrogate
from excavator_surrogate.surrogate.rollout import rollout

sys.path.insert(0, str(Path(__file__).parent))
from ensemble import member

SHAPES = ((2, 64), (2, 128), (3, 64), (4, 128), (6, 128))
"""(members, units per member): the demo's 2 x 64 and the recipe's 4-6 x 128."""
BATCHES = (2, 13)
"""Free-run batches: a validation split of two sessions, and a test set of 13."""


def paired(
    surs: list[Surrogate], theta: np.ndarray, u: np.ndarray, repeats: int
) -> tuple[list[float], float, list[np.ndarray]]:
    """Time ``rollout(sur, theta, u)`` for the two surrogates in pairs, the order swapped
    every pair, after one warm-up run each.

    Returns:
        Each one's median seconds per step, the median of the pairs' ratios (second / first:
        pairing keeps the ratio meaningful when the machine's speed drifts), and the angles.
    """
    for sur in surs:
        rollout(sur, theta[:, :40], u[:, :40])
    times: list[list[float]] = [[], []]
    out: list[np.ndarray] = [np.empty(0), np.empty(0)]
    for r in range(repeats):
        for i in (0, 1) if r % 2 == 0 else (1, 0):
            t0 = time.perf_counter()
            out[i], _ = rollout(surs[i], theta, u)
            times[i].append((time.perf_counter() - t0) / u.shape[1])
    ratios = [b / a for a, b in zip(*times)]
    return [float(np.median(t)) for t in times], float(np.median(ratios)), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300, help="free-run steps per run")
    ap.add_argument("--repeats", type=int, default=8, help="timed pairs per row")
    args = ap.parse_args()
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    rows, ok_recipe, noise, max_diff = [], True, 0.0, 0.0
    print("| members x units | batch | merged [ms/step] | blocks [ms/step] | blocks / merged |")
    print("|---|---|---|---|---|")
    for m, h in SHAPES:
        ens = merge([member(s, h) for s in range(m)])
        whole = replace(ens, metrics=None)  # no merge record: the merged network's own cells
        for n in BATCHES:
            theta = np.cumsum(rng.normal(scale=0.01, size=(n, args.steps, 4)), axis=1)
            u = rng.uniform(-900, 900, size=(n, args.steps, 4))
            (t_m, t_b), ratio, (th_m, th_b) = paired([whole, ens], theta, u, args.repeats)
            max_diff = max(max_diff, float(np.abs(th_b - th_m).max()))
            split = m * h >= MIN_SPLIT_WIDTH
            if not split:  # the same code twice: the measurement's noise
                noise = max(noise, abs(ratio - 1.0))
            elif m >= 4:  # the recipe's ensembles
                ok_recipe &= ratio <= (0.9 if n <= 2 else 0.5)
            rows.append({"members": m, "units": h, "batch": n, "split": split, "ratio": ratio})
            print(f"| {m} x {h} | {n} | {t_m * 1e3:.3f} | {t_b * 1e3:.3f} | {ratio:.2f} |")
    print(f"noise: the unsplit rows (the same code twice) differ by up to {noise:.0%}")
    result = {
        "bench": "blocks",
        "torch": torch.__version__,
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "min_split_width": MIN_SPLIT_WIDTH,
        "rows": rows,
        "noise": noise,
        "max_theta_diff_rad": max_diff,
        "goals": {
            "recipe_ensembles_0.9x_at_batch_2_0.5x_at_13": bool(ok_recipe),
            "noise_within_10pct": bool(noise <= 0.1),
            "same_run_1e-4_rad": bool(max_diff <= 1e-4),
        },
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
