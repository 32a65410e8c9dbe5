"""Benchmark: the dry run's speed probe against whole epochs, side by side.

``exsur run --dry-run`` and ``exsur train --dry-run`` time a network the cost model does not
cover against the recipe's (``training/speed_probe.py``: about 5 s of short bursts on copies
of two synthetic episodes) and scale the reference machine's times by the ratio.  This
checks that ratio against the one whole epochs give: for each config below, the config's
network and the reference network (``speed_probe.reference_config``: ``plan.STEP_NET``'s
network in ``plan.STEP_SHAPE``'s sub-sequences) train
:data:`EPOCHS` whole epochs each, alternately, on a training split the size of a real one
(:data:`N_EPISODE` synthetic episodes of :data:`N_STEP` samples), and free-run the demo's
validation shape (two episodes of 2000 samples); then the probe runs as a dry run runs it.

Configs: the recipe itself (a control: both ratios near 1), the recipe as a GRU, the recipe
at 64 units, the demo's (``quick-hydraulic``: 64 units, free-run feedback, batches of 64,
the velocity input) and ``paper-noload``'s.

Goals: the probe's training ratio within :data:`GOAL_TRAIN` of the whole epochs' for every
config (it is most of a training's time), and so is its ratio in a free-run-feedback config's
teacher-forced epochs (the demo's and ``paper-noload``'s first 3, timed as epoch 0); its
validation ratio within :data:`GOAL_VAL`.
Ends with one JSON line with a ``goals`` object of booleans.  Usage::

    python bench/estimate.py            # one core per network, as the trainings run; ~3 min
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from dataclasses import replace

import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.pipeline import resolve_run
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training.auto import auto_config
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.estimate import teacher_forced_epochs
from excavator_surrogate.training.speed_probe import (
    ThrowawayNetwork,
    measure_speed,
    reference_config,
    side_by_side,
)

N_EPISODE = 40
"""Training episodes of the whole-epoch runs (about 990 sub-sequences of the demo's 150)."""
N_STEP = 3000
"""Samples per training episode (the demo's)."""
EPOCHS = 2
"""Whole epochs per network and config (alternating with the reference's)."""
GOAL_TRAIN = 1.25
"""The probe's training ratio is within this factor of the whole epochs' (either way)."""
GOAL_VAL = 1.5
"""The probe's validation ratio is within this factor of the whole validation runs'."""


def _parse() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--epochs", type=int, default=EPOCHS, help="whole epochs per network")
    return p.parse_args()


def _configs(ds: Dataset) -> dict[str, TrainConfig]:
    recipe, _ = auto_config(ds, cpus=1)
    recipe = replace(recipe, members=1, prior_choice=False)
    return {
        "recipe": recipe,
        "recipe_gru": replace(recipe, cell="gru"),
        "recipe_64": replace(recipe, hidden=64, head_hidden=64),
        "demo": resolve_run().configs["train"],
        "paper_noload": resolve_run(preset="paper-noload").configs["train"],
    }


def whole_epochs(
    cfg: TrainConfig, ds: Dataset, *, epochs: int
) -> tuple[float, float | None, float]:
    """``cfg``'s network over the reference network: (training time per sub-sequence step
    over ``epochs`` whole epochs, the same in its teacher-forced warm-up's epochs (None
    without one), validation free-run time), alternating, medians."""
    pieces: list[Callable[[ThrowawayNetwork], float]] = [lambda n: n.train_epoch()]
    if teacher_forced_epochs(cfg):
        pieces.append(lambda n: n.train_epoch(epoch=0))
    train, val = side_by_side(
        (cfg, reference_config(cfg)),
        ds.spec,
        ds.train,
        ds.val,
        rounds=epochs,
        train=pieces,
        warmup_s=0.5,
    )
    return train[0], (train[1] if len(train) > 1 else None), val


def main() -> None:
    args = _parse()
    torch.set_num_threads(1)
    spec = synthetic_spec(4)
    ds = Dataset(spec=spec)
    ds.episodes["train"] = [
        synthetic_episode(spec, kind="sine" if i % 2 else "step", n_step=N_STEP, seed=i)
        for i in range(N_EPISODE)
    ]
    ds.episodes["val"] = [synthetic_episode(spec, n_step=2000, seed=900 + i) for i in range(2)]
    rows: dict[str, dict[str, float]] = {}
    t0 = time.perf_counter()
    for name, cfg in _configs(ds).items():
        train_r, teacher_r, val_r = whole_epochs(cfg, ds, epochs=args.epochs)
        probe = measure_speed(cfg, n_joint=spec.n_joint)
        rows[name] = {
            "epochs_train_ratio": train_r,
            "probe_train_ratio": probe.train,
            "train_probe_over_epochs": probe.train / train_r,
            "epochs_val_ratio": val_r,
            "probe_val_ratio": probe.val,
            "val_probe_over_epochs": probe.val / val_r,
            "probe_s": probe.seconds,
        }
        r = rows[name]
        line = (
            f"{name:13s} training: whole epochs {train_r:.2f}x, probe {probe.train:.2f}x "
            f"({r['train_probe_over_epochs']:.2f}); "
        )
        if teacher_r is not None:  # a probe without the warm-up's ratio fails the goal (nan)
            got = math.nan if probe.teacher is None else probe.teacher
            r.update(
                epochs_teacher_ratio=teacher_r,
                probe_teacher_ratio=got,
                teacher_probe_over_epochs=got / teacher_r,
            )
            line += (
                f"teacher-forced: {teacher_r:.2f}x, probe {got:.2f}x "
                f"({r['teacher_probe_over_epochs']:.2f}); "
            )
        line += (
            f"validation: {val_r:.2f}x, probe {probe.val:.2f}x "
            f"({r['val_probe_over_epochs']:.2f}); probe {probe.seconds:.1f} s"
        )
        print(line, flush=True)

    def within(key: str, factor: float) -> bool:
        """Every config that has the ratio has it within ``factor``, and some config has it."""
        got = [r[key] for r in rows.values() if key in r]
        return bool(got) and all(abs(math.log(v)) <= math.log(factor) for v in got)

    out = {
        "bench": "estimate",
        "threads": torch.get_num_threads(),
        "seconds": time.perf_counter() - t0,
        "configs": rows,
        "goals": {
            "probe_train_within": within("train_probe_over_epochs", GOAL_TRAIN),
            "probe_teacher_within": within("teacher_probe_over_epochs", GOAL_TRAIN),
            "probe_val_within": within("val_probe_over_epochs", GOAL_VAL),
        },
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
