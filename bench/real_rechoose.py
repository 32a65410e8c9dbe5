"""The recipe's choices made again on a finished ``bench/real.py`` run, with the code on the path.

The kind choice (plain against map-correcting networks, per joint; ``training/kinds.py``) and
the static map choice (``training/map_joints.py``) run after the networks have trained, on
their validation free runs, so a change to either rule needs no new training to measure.
This script loads the networks that ``python bench/real.py --work DIR`` kept
(``DIR/<shape>_auto_seedS/{plain,prior}/member_*/best.pt``, or ``member_*`` alone without the
kind choice), makes both choices again as ``exsur train`` makes them, and scores the result
as ``bench/real.py`` does: on the scored split and, for the simulated shapes, on the more
test data it simulated (``DIR/<shape>_more``), beside the structured baseline.  With the rules
unchanged it reproduces ``bench/real.py``'s recipe rows to the digit (the choices are
deterministic functions of the saved networks and the data).

Usage::

    python bench/real_rechoose.py --work DIR --shape continuous [--seeds 0,10,20] [--sim-seed N]
                                  [--set train.KEY=VALUE ...]

A run that trained more networks than today's plan has stands in for it: the plan's first
``members`` plain and ``prior_members(members)`` map-correcting networks are the ones a run of
the plan trains (a member's seed and training do not depend on how many there are, as long
as no wall-time cap cut them).

``--set`` changes the ``[train]`` fields the choices read (``prior_choice``, ``prior_drive``,
``prior_margin``, ``prior_blend``, ``prior_skip_pinned``, ``static_map``, ``map_periodic``,
``map_parallel``, ``map_blocks``; e.g. ``--set train.prior_drive=validation``, the choice of
sessions 25-86, or ``--set train.map_blocks=false``, the map choice before session 100).
``--sim-seed`` and ``--rate-hz`` must be the
ones the run simulated (its JSON line's ``sim_seed`` and ``rate_hz``).  Prints each seed's choices and a table per
scored set, and ends with ONE JSON line whose ``goals`` say whether the median beats the
structured baseline on every joint and whether every seed chose what its ``best.pt`` records
(``same_choices_as_recorded``: expected whenever the rules and ``--set`` are the run's).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from excavator_surrogate.config import parse_sets
from excavator_surrogate.data import load_dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.io_utils import setup_logging
from excavator_surrogate.surrogate.checkpoint import load_checkpoint
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.structured import fit_structured
from excavator_surrogate.surrogate.validation import free_run_error
from excavator_surrogate.training.auto import auto_config
from excavator_surrogate.training.batches import split_episodes
from excavator_surrogate.training.kinds import (
    choice_joints,
    choice_options,
    choose_kinds,
)
from excavator_surrogate.training.map_joints import choose_map_joints, map_options
from excavator_surrogate.training.net_gain import after_map_choice
from excavator_surrogate.training.plan import prior_members

sys.path.insert(0, str(Path(__file__).parent))
from real import WARMUP
from real_cases import CASES, saved_more
from real_scores import score, shown

STRUCTURED = "structured (dead zone, gain, delay, end stops)"


def members(run: Path, kind: str) -> list:
    """The saved networks of one kind (``plain`` / ``prior``) of a recipe run, in member order."""
    paths = list((run / kind).glob("member_*/best.pt"))
    if not paths and kind == "plain":  # a run without the kind choice
        paths = list(run.glob("member_*/best.pt"))
    paths.sort(key=lambda p: int(p.parent.name.removeprefix("member_")))
    return [load_checkpoint(p) for p in paths]


def rechoose(run: Path, cfg, train_eps, val_eps) -> tuple:
    """The model ``exsur train`` would make from the networks saved in ``run`` under ``cfg``'s
    choice fields (fitted on ``train_eps``, chosen on ``val_eps``: ``split_episodes``), and
    the records of the two choices and of the network joints' speeds (None where one is
    off)."""
    # a plan of fewer members trains the first networks of one of more (a member's seed and
    # training do not depend on how many there are), so a run of more stands in for it
    plains = members(run, "plain")[: cfg.members]
    priors = members(run, "prior")[: prior_members(cfg.members)]
    if not plains:
        raise SystemExit(f"{run}: no saved networks (member_*/best.pt); run bench/real.py --work")
    kinds = None
    if cfg.prior_choice and priors:
        joints = choice_joints(cfg, plains[0], train_eps, val_eps)
        model, kinds = choose_kinds(plains, priors, val_eps, **joints, **choice_options(cfg))
    else:
        model = merge(plains) if len(plains) > 1 else plains[0]
    maps = None
    if cfg.static_map:
        new, maps = choose_map_joints(model, train_eps, val_eps, **map_options(cfg))
        model = new if new is not None else model
    gains = None
    if cfg.net_val_gain:
        new, gains = after_map_choice(
            model,
            train_eps,
            val_eps,
            map_record=maps,
            min_span=cfg.choice_min_span,
            trained_on_val=cfg.train_on_val,
            max_steps=cfg.val_steps or None,
        )
        model = new if new is not None else model
    return model, kinds, maps, gains


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True, help="a bench/real.py --work folder")
    ap.add_argument("--shape", choices=list(CASES), required=True, help="data shape")
    ap.add_argument("--seeds", default="0,10,20", help="comma-separated recipe seeds")
    ap.add_argument("--sim-seed", type=int, default=0, help="the run's --sim-seed")
    ap.add_argument("--rate-hz", type=float, default=None, help="the run's --rate-hz")
    ap.add_argument(
        "--set", action="append", default=[], metavar="train.KEY=VALUE", help="a choice field"
    )
    args = ap.parse_args()
    setup_logging()
    try:
        sets = parse_sets(args.set, sections=["train"])
    except ConfigError as e:
        raise SystemExit(f"real_rechoose: {e}") from None
    overrides = dict(sets.get("train", {}))
    data_dir = args.work / args.shape
    if not data_dir.is_dir():
        raise SystemExit(f"{data_dir}: no dataset; run bench/real.py --work {args.work} first")
    ds = load_dataset(data_dir)
    split = "val" if args.shape == "h1" else "test"
    more = saved_more(args.work, args.shape, args.sim_seed, ds.spec, args.rate_hz)
    factor, units = shown(ds.spec)
    names = list(ds.spec.names)

    structured = fit_structured(ds.train, window=WARMUP)
    rows = {STRUCTURED: score(structured, ds.split(split))}
    more_rows = {STRUCTURED: score(structured, more)} if more else {}
    seeds = [int(s) for s in args.seeds.split(",")]
    same, per_seed = [], {}
    for seed in seeds:
        run = args.work / f"{args.shape}_auto_seed{seed}"
        cfg, _ = auto_config(ds, overrides={"seed": seed, "tensorboard": False, **overrides})
        train_eps, val_eps = split_episodes(cfg, ds)
        model, kinds, maps, gains = rechoose(run, cfg, train_eps, val_eps)
        recorded = (load_checkpoint(run / "best.pt").metrics or {}).get("training", {})
        now = {
            "kinds": None if kinds is None else kinds["chosen"],
            "static_map": None if maps is None else maps["chosen"],
            "net_val_gain": None if gains is None else gains["joints"],
        }
        then = {
            k: (recorded.get(k) or {}).get("joints" if k == "net_val_gain" else "chosen")
            for k in now
            if k != "net_val_gain" or k in recorded  # a run before session 111 has none
        }
        same.append(all(now[k] == v for k, v in then.items()))
        label = f"recipe, seed {seed}"
        rows[label] = score(model, ds.split(split))
        if more:
            more_rows[label] = score(model, more)
        val = free_run_error(model, val_eps, max_steps=cfg.val_steps or None)
        per_seed[seed] = {
            **now,
            "recorded": then,
            "why": [r["why"] for r in (kinds, maps, gains) if r is not None],
            "val_rmse": [round(float(v), 3) for v in factor * np.asarray(val["theta_rmse"])],
        }
        print(f"seed {seed}: kinds {now['kinds']}, static map {now['static_map']}")
        for why in per_seed[seed]["why"]:
            print(f"  {why}")

    head = " | ".join(f"{n} [{u}]" for n, u in zip(names, units))
    out: dict = {"bench": "real_rechoose", "shape": args.shape, "set": overrides, "seeds": per_seed}
    goals: dict = {"same_choices_as_recorded": all(same)}
    for tag, table, where in (("", rows, split), ("more_", more_rows, "more test data")):
        if not table:
            continue
        median = np.median([table[f"recipe, seed {s}"]["rmse"] for s in seeds], axis=0)
        print(f"\n[{args.shape}] free-run position RMSE (R^2) on {where}")
        print(f"| model | {head} |")
        print("|---|" + "---|" * len(names))
        for label, r in table.items():
            cells = " | ".join(f"{e:.2f} ({q:.3f})" for e, q in zip(r["rmse"], r["r2"]))
            print(f"| {label} | {cells} |")
        print(f"| recipe, median of {len(seeds)} | {' | '.join(f'{v:.2f}' for v in median)} |")
        out[f"{tag}median_rmse"] = [round(float(v), 3) for v in median]
        out[f"{tag}rmse"] = {k: [round(v, 3) for v in r["rmse"]] for k, r in table.items()}
        goals[f"{tag}median_beats_structured_every_joint"] = bool(
            np.all(median < np.array(table[STRUCTURED]["rmse"]))
        )
    out["goals"] = goals
    print(json.dumps(out))


if __name__ == "__main__":
    main()
