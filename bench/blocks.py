"""Free runs of merged seed ensembles: the merged network against its member blocks.

A batched free run (:func:`~excavator_surrogate.surrogate.rollout.rollout`, what validation,
the recipe's choices and evaluation run) steps a merged ensemble as its member blocks
(:mod:`excavator_surrogate.surrogate.blocks`) from :data:`MIN_SPLIT_WIDTH` merged units on.
This times the same free run both ways, side by side in one process, for untrained
paper-size members (2 x ``h`` LSTM, head ``h``): ``merged`` is the merged network's own
cells (its merge record removed, so it is not split), ``blocks`` the default.  Ratios are
``blocks / merged`` per step (min of ``--repeats``), one torch thread (a member's setting).
Models are untrained: speed does not depend on training.

Goals: every split shape at most 0.9x the merged time at each batch, the narrow one (two
members of 64, not split) within 1.1x (it is the same code), and the two runs' angles within
1e-4 rad.  Ends with ONE JSON line.  Usage::

    python bench/blocks.py [--steps 300] [--repeats 5]
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


def timed(
    surs: list[Surrogate], theta: np.ndarray, u: np.ndarray, repeats: int
) -> list[tuple[float, np.ndarray]]:
    """Per surrogate: min seconds per step of ``rollout(sur, theta, u)`` over ``repeats``
    runs taken in turns after one warm-up run each, and its angles."""
    for sur in surs:
        rollout(sur, theta[:, :40], u[:, :40])
    best = [float("inf")] * len(surs)
    out: list[np.ndarray] = [np.empty(0)] * len(surs)
    for _ in range(repeats):
        for i, sur in enumerate(surs):
            t0 = time.perf_counter()
            out[i], _ = rollout(sur, theta, u)
            best[i] = min(best[i], (time.perf_counter() - t0) / u.shape[1])
    return list(zip(best, out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300, help="free-run steps per run")
    ap.add_argument("--repeats", type=int, default=5, help="runs per variant (min is kept)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    rows, ok_split, ok_narrow, max_diff = [], True, True, 0.0
    print("| members x units | batch | merged [ms/step] | blocks [ms/step] | blocks / merged |")
    print("|---|---|---|---|---|")
    for m, h in SHAPES:
        ens = merge([member(s, h) for s in range(m)])
        whole = replace(ens, metrics=None)  # no merge record: the merged network's own cells
        for n in BATCHES:
            theta = np.cumsum(rng.normal(scale=0.01, size=(n, args.steps, 4)), axis=1)
            u = rng.uniform(-900, 900, size=(n, args.steps, 4))
            (t_m, th_m), (t_b, th_b) = timed([whole, ens], theta, u, args.repeats)
            ratio = t_b / t_m
            max_diff = max(max_diff, float(np.abs(th_b - th_m).max()))
            split = m * h >= MIN_SPLIT_WIDTH
            if split:
                ok_split &= ratio <= 0.9
            else:
                ok_narrow &= ratio <= 1.1
            rows.append({"members": m, "units": h, "batch": n, "split": split, "ratio": ratio})
            print(f"| {m} x {h} | {n} | {t_m * 1e3:.3f} | {t_b * 1e3:.3f} | {ratio:.2f} |")
    result = {
        "bench": "blocks",
        "torch": torch.__version__,
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "min_split_width": MIN_SPLIT_WIDTH,
        "rows": rows,
        "max_theta_diff_rad": max_diff,
        "goals": {
            "split_at_most_0.9x": bool(ok_split),
            "narrow_within_1.1x": bool(ok_narrow),
            "same_run_1e-4_rad": bool(max_diff <= 1e-4),
        },
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
