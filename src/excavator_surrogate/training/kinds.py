"""Two kinds of network, chosen per joint: ``[train] prior_choice = true``.

A network trained from scratch and one that corrects the static valve map (``prior``: dead
zone, gain per direction, delay) generalise differently, and not alike on every joint: on
the stand-in sessions case the map-correcting networks drove the boom and the bucket better
on validation and on the test day, the plain ones the arm (docs/real.md).  With
``prior_choice`` the ensemble's members are trained in both ways on the same seeds: half of
them plain, half correcting the map (the same number of trainings as the plain ensemble, so
the same budget).  Each half is merged and scored by its validation free run, and then:

1. a joint is a candidate for the map-correcting networks if their validation angle RMSE
   on it is lower than the plain ones' by :data:`PRIOR_MARGIN` (a near tie stays plain);
2. for the candidates, and for each candidate alone, a **composite** is built: member pair
   ``i`` (plain ``i``, map-correcting ``i``, the same seed) becomes one network whose
   candidate joints come from the map-correcting network and the others from the plain one
   (:func:`~excavator_surrogate.surrogate.ensemble.merge` with ``joint_weights``), and the
   pairs are merged into the ensemble;
3. the best set whose validation error is at most :data:`SET_MARGIN` above the plain half's,
   overall and on every joint, is kept (a joint's choice changes the angles the others
   read); if none, or no candidate, the plain half is the model; if every joint prefers the
   map-correcting half, that half is.

The static map choice (``static_map``) then runs on the result as on any model.

Layout: ``OUT/plain/member_*`` and ``OUT/prior/member_*`` (the trained networks),
``OUT/best.pt`` (the model; ``metrics.training.kinds`` says what was chosen and why),
``OUT/config.toml`` (``[kinds]``: the same), ``OUT/log.csv`` (one row per network).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from ..data.dataset import Dataset
from ..surrogate.checkpoint import load_checkpoint
from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from ..surrogate.prior import PRIOR_MAP
from ..surrogate.structured import with_map_joints
from ..surrogate.validation import free_run_error
from .config import TrainConfig
from .ensembles import member_configs, merge_members, open_run, train_member
from .jobs import TrainJob, run_jobs
from .map_joints import SET_MARGIN, best_set
from .records import write_config

_log = logging.getLogger(__name__)

PRIOR_MARGIN = 0.05
"""Relative margin by which the map-correcting networks must beat the plain ones on a
joint's validation angle RMSE for the joint to be a candidate (a tie stays plain)."""

KINDS = ("plain", "prior")


def in_prior_form(plain: Surrogate, prior: Surrogate) -> Surrogate:
    """``plain`` (no map) as a network that reads ``prior``'s features and carries its map
    with zero gains: the same output, ready to be merged with ``prior``."""
    p = prior.net.prior
    n_joint = plain.spec.n_joint
    fit = {k: getattr(p, k).tolist() for k in PRIOR_MAP}  # no joint on it: gains 0
    return with_map_joints(plain, fit, [False] * n_joint, lags=prior.norm.lags or None)


def composite(
    plains: Sequence[Surrogate], priors: Sequence[Surrogate], use_prior: Sequence[bool]
) -> Surrogate:
    """The ensemble of member pairs, each pair one network whose joints ``use_prior`` come
    from the map-correcting member and the others from the plain one.

    Args:
        plains: K plain networks; priors: K map-correcting networks (pair ``i`` = the same
            seed).
        use_prior: (n_joint,) which joints the map-correcting networks drive.
    """
    if not any(use_prior):
        return merge(list(plains))
    if all(use_prior):
        return merge(list(priors))
    w = [[0.0 if p else 1.0 for p in use_prior], [1.0 if p else 0.0 for p in use_prior]]
    pairs = [
        merge([in_prior_form(a, b), b], joint_weights=w, name=f"{b.name}-composite")
        for a, b in zip(plains, priors)
    ]
    return merge(pairs)


def choose_kinds(
    plains: Sequence[Surrogate],
    priors: Sequence[Surrogate],
    val: Sequence[Any],
    *,
    max_steps: int | None = None,
) -> tuple[Surrogate, dict[str, Any]]:
    """The model of the two halves (see the module docstring) and the record of the choice.

    Returns:
        ``(model, record)``; ``record`` holds both halves' validation scores, the candidate
        joints, the sets tried and what was chosen, with a one-line ``why``.
    """
    names = list(plains[0].spec.names)
    merged = {"plain": merge(list(plains)), "prior": merge(list(priors))}
    vals = {k: free_run_error(m, list(val), max_steps=max_steps) for k, m in merged.items()}
    base = vals["plain"]
    cand = [
        bool(b < (1 - PRIOR_MARGIN) * a)
        for a, b in zip(base["theta_rmse"], vals["prior"]["theta_rmse"])
    ]
    record: dict[str, Any] = {
        "names": names,
        "val_theta_rmse_plain": base["theta_rmse"],
        "val_theta_rmse_prior": vals["prior"]["theta_rmse"],
        "val_error_plain": base["val_error"],
        "val_error_prior": vals["prior"]["val_error"],
        "candidates": [n for n, c in zip(names, cand) if c],
        "tried": [],
        "chosen": [],
    }
    if not any(cand):
        record["why"] = (
            f"the map-correcting networks beat the plain ones by {PRIOR_MARGIN:.0%} on no "
            "joint's validation free run: the plain networks drive every joint"
        )
        return merged["plain"], record
    build = partial(composite, plains, priors)  # joints -> the composite taking them
    best = best_set(cand, build, base, val, record=record, max_steps=max_steps)
    if best is None:
        record["why"] = (
            f"every set of joints on the map-correcting networks is worse than the plain "
            f"networks' validation error {base['val_error']:.4g} by more than "
            f"{SET_MARGIN:.0%}, overall or on a joint: the plain networks drive every joint"
        )
        return merged["plain"], record
    model, got, joints = best
    record["chosen"] = [n for n, p in zip(names, joints) if p]
    record["why"] = (
        f"{', '.join(record['chosen'])} from the map-correcting networks: validation error "
        f"{got['val_error']:.4g} against the plain networks' {base['val_error']:.4g}"
    )
    return model, record


def train_choosing_kinds(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    show_progress: bool | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train ``cfg.members`` networks, half plain and half correcting the static map (the same
    seeds), and keep per joint the kind that validates better (see the module docstring);
    returns ``OUT/best.pt``."""
    half = max(1, cfg.members // 2)
    val_eps, out, workers = open_run(cfg, dataset, out, notes=notes, trainings=2 * half)
    _log.info(
        f"two kinds of network: {half} plain and {half} correcting the static map (same "
        f"seeds), {workers} in parallel; per joint, the kind that validates better"
    )
    t0 = time.monotonic()
    # the members are single networks: the static map choice runs on the model they make
    base = replace(cfg, prior_choice=False, members=half, static_map=False)
    cfgs = {"plain": member_configs(base), "prior": member_configs(replace(base, prior=True))}
    jobs = [
        TrainJob(cfg=c, dataset=dataset, out=out / k / f"member_{i}", tag=f"exsur {k} {i}")
        for k in KINDS
        for i, c in enumerate(cfgs[k])
    ]
    paths = run_jobs(train_member, jobs, workers=workers, show_progress=show_progress)
    nets = {
        k: [load_checkpoint(p) for p in paths[i * half : (i + 1) * half]]
        for i, k in enumerate(KINDS)
    }
    model, record = choose_kinds(
        nets["plain"], nets["prior"], val_eps, max_steps=cfg.val_steps or None
    )
    _log.info(f"two kinds of network: {record['why']}")
    best = merge_members(
        cfg,
        cfgs["plain"] + cfgs["prior"],
        nets["plain"] + nets["prior"],
        val_eps,
        out=out,
        t0=t0,
        training={"kinds": record},
        merged=model,
        column=("kind", [k for k in KINDS for _ in range(half)], "composite"),
    )
    write_config(out, cfg, notes={**(notes or {}), "kinds": record})
    return best
