"""deepSI's SUBNET, the hidden wheel loader's best peer on the bucket, on a ``bench/real.py`` run.

The issue's tables of the hidden machines name their peers: a plain 2x128 LSTM (which
``bench/real.py`` trains itself) and deepSI 0.4.4's SUBNET with its defaults, which led the
wheel loader's bucket (11.2 degrees against the plain LSTM's 14.0).  This script trains SUBNET
on the data of a finished ``python bench/real.py --work DIR --shape S`` run and scores it as
``bench/real.py`` scores the recipe: a free run of each scored episode after a warm-up of
:data:`~real.WARMUP` measured samples (SUBNET's encoder reads the last ``max(na, nb)`` of
them), the position RMSE and R^2 per joint pooled over the episodes, in each joint's shown
unit, on the scored split and on the more test data the run simulated.  Beside it, the
recipe's saved models (``DIR/<shape>_auto_seedS/best.pt``) scored the same way.

SUBNET as its defaults give it: ``SUBNET(nu, ny, norm)`` (state of 10, encoder of the past
20 commands and outputs, residual MLPs), ``fit(model, train, val, n_its, T=50,
batch_size=256, val_freq=250)`` with Adam at its default rate; deepSI keeps the iterate with
the lowest validation simulation error.  Its outputs are the joints' positions (the swing
unwrapped), from the commands and any exogenous inputs.  deepSI is not a dependency of
exsur::

    pip install deepSI==0.4.4
    python bench/real_subnet.py --work DIR --shape loader-7min [--sim-seed N] [--rate-hz HZ]
                                [--seeds 0,1] [--iterations 5000] [--recipe-seeds 0,10,20]

``--sim-seed`` and ``--rate-hz`` must be the run's.  deepSI's own checkpoints go to
``DIR/subnet_checkpoints``, not the home folder.  Ends with ONE JSON line whose ``goals`` say
whether the recipe's median beats SUBNET's on every joint (scored split, more test data).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from excavator_surrogate.data import load_dataset
from excavator_surrogate.surrogate.angles import wrap_periodic
from excavator_surrogate.surrogate.checkpoint import load_checkpoint

sys.path.insert(0, str(Path(__file__).parent))
from real import WARMUP
from real_cases import CASES, saved_more
from real_scores import score, shown


def _io(ep, spec, io_data):
    """One episode as deepSI's data: ``u`` (n_step, n_u), ``y`` the positions (n_step,
    n_joint), periodic joints unwrapped, float32."""
    y = ep.theta.copy()
    per = np.asarray(spec.periodic, dtype=bool)
    y[:, per] = np.unwrap(y[:, per], axis=0)
    u = np.ascontiguousarray(ep.u, dtype=np.float32)
    return io_data(u=u, y=np.ascontiguousarray(y, dtype=np.float32), sampling_time=spec.dt)


def subnet_score(model, episodes, spec, io_data) -> dict[str, list[float]]:
    """Free-run position RMSE and R^2 per joint of ``model`` over ``episodes`` after the
    warm-up, pooled, in each joint's shown unit (as :func:`real_scores.score`)."""
    n_enc = max(model.na, model.nb)
    err, ref = [], []
    for ep in episodes:
        d = _io(ep, spec, io_data)
        cut = io_data(
            u=np.ascontiguousarray(d.u[WARMUP - n_enc :]),
            y=np.ascontiguousarray(d.y[WARMUP - n_enc :]),
            sampling_time=spec.dt,
        )
        with torch.no_grad():
            y_hat = model.simulate(cut).y[n_enc:]
        err.append(wrap_periodic(y_hat - d.y[WARMUP:], spec.periodic))
        ref.append(d.y[WARMUP:])
    e, r = np.concatenate(err), np.concatenate(ref)
    factor = shown(spec)[0]
    rmse = np.sqrt((e**2).mean(axis=0))
    r2 = 1.0 - (e**2).sum(axis=0) / ((r - r.mean(axis=0)) ** 2).sum(axis=0)
    return {"rmse": (factor * rmse).tolist(), "r2": r2.tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, required=True, help="a bench/real.py --work folder")
    ap.add_argument("--shape", choices=list(CASES), required=True, help="data shape")
    ap.add_argument("--sim-seed", type=int, default=0, help="the run's --sim-seed")
    ap.add_argument("--rate-hz", type=float, default=None, help="the run's --rate-hz")
    ap.add_argument("--seeds", default="0,1", help="comma-separated SUBNET (torch) seeds")
    ap.add_argument("--iterations", type=int, default=5000, help="SUBNET's batch updates")
    ap.add_argument("--recipe-seeds", default="0,10,20", help="the run's recipe seeds")
    args = ap.parse_args()
    try:
        import deepSI
        from nonlinear_benchmarks import Input_output_data
    except ImportError as e:
        raise SystemExit(f"real_subnet: needs deepSI ({e}); pip install deepSI==0.4.4") from None
    data_dir = args.work / args.shape
    if not data_dir.is_dir():
        raise SystemExit(f"{data_dir}: no dataset; run bench/real.py --work {args.work} first")
    ckpts = args.work / "subnet_checkpoints"
    ckpts.mkdir(exist_ok=True)
    deepSI.fitting.get_checkpoint_dir = lambda: str(ckpts)  # not ~/.deepSI-checkpoints

    ds = load_dataset(data_dir)
    spec = ds.spec
    split = "val" if args.shape == "h1" else "test"
    more = saved_more(args.work, args.shape, args.sim_seed, spec, args.rate_hz)
    train = [_io(ep, spec, Input_output_data) for ep in ds.train]
    val = [_io(ep, spec, Input_output_data) for ep in ds.val]
    sets = {split: list(ds.split(split)), **({"more": more} if more else {})}

    rows: dict[str, dict[str, dict]] = {k: {} for k in sets}
    times = {}
    for seed in (int(s) for s in args.seeds.split(",")):
        torch.manual_seed(seed)
        nu, ny, norm = deepSI.get_nu_ny_and_auto_norm(train)
        model = deepSI.SUBNET(nu, ny, norm)
        t0 = time.monotonic()
        deepSI.fitting.fit(
            model, train, val if len(val) > 1 else val[0], n_its=args.iterations, T=50,
            batch_size=256, val_freq=250,
        )  # fmt: skip
        times[seed] = round(time.monotonic() - t0, 1)
        for k, eps in sets.items():
            rows[k][f"SUBNET, seed {seed}"] = subnet_score(model, eps, spec, Input_output_data)
    recipe_seeds = [int(s) for s in args.recipe_seeds.split(",")]
    for s in recipe_seeds:
        sur = load_checkpoint(args.work / f"{args.shape}_auto_seed{s}" / "best.pt")
        for k, eps in sets.items():
            rows[k][f"recipe, seed {s}"] = score(sur, eps)

    names, units = list(spec.names), shown(spec)[1]
    out: dict = {"bench": "real_subnet", "shape": args.shape, "sim_seed": args.sim_seed}
    out["subnet_train_s"] = times
    goals = {}
    for k, table in rows.items():
        med = {
            who: np.median([r["rmse"] for lab, r in table.items() if lab.startswith(who)], axis=0)
            for who in ("SUBNET", "recipe")
        }
        print(f"\n[{args.shape}] free-run position RMSE (R^2) on {k}")
        print("| model | " + " | ".join(f"{n} [{u}]" for n, u in zip(names, units)) + " |")
        print("|---|" + "---|" * len(names))
        for label, r in table.items():
            cells = " | ".join(f"{e:.2f} ({q:.3f})" for e, q in zip(r["rmse"], r["r2"]))
            print(f"| {label} | {cells} |")
        for who, m in med.items():
            print(f"| {who}, median | " + " | ".join(f"{v:.2f}" for v in m) + " |")
            out[f"{k}_{who.lower()}_median_rmse"] = [round(float(v), 3) for v in m]
        tag = "" if k == split else "more_"
        goals[f"{tag}recipe_median_beats_subnet_every_joint"] = bool(
            np.all(med["recipe"] < med["SUBNET"])
        )
    out["goals"] = goals
    print(json.dumps(out))


if __name__ == "__main__":
    main()
