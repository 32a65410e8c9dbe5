"""Exogenous inputs that must not hurt: ``[train] exogenous = "choose"``.

A throttle, a gear or a run condition (``spec.inputs``) may help one joint and hurt
another on held-out data.  With ``choose`` the ensemble's members are trained in two ways
on the same seeds: half of them use the inputs, half ignore them (their input weights held
at zero, :func:`~.loop.blind_inputs`).  Each half is merged and scored by its validation
free run; the inputs are kept only if that half is better by :data:`INPUT_MARGIN` overall
and no joint's angle RMSE is worse by more than it.  The remaining members are then trained
the chosen way and merged with the winning half, so the result is an ensemble of
``members`` networks, as without inputs (the recipe plans the epochs for the
``members + members // 2`` trainings within the same budget).  With ``prior_choice`` the
kind choice's map-correcting networks (:mod:`.kinds`) train beside the rest, the chosen
way, and the kinds are chosen per joint on the result.

Layout: ``OUT/member_*`` (the ensemble's members, as for any ensemble: the winning half,
then the rest), ``OUT/use/member_*`` or ``OUT/ignore/member_*`` (the losing half),
``OUT/prior/member_*`` (with ``prior_choice``), ``OUT/best.pt`` (the merged ensemble,
``metrics.training.exogenous`` and ``kinds`` say what was chosen and why),
``OUT/config.toml`` (``[exogenous]``, ``[kinds]``: the same).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..data.dataset import Dataset
from ..surrogate.checkpoint import load_checkpoint
from ..surrogate.ensemble import merge
from ..surrogate.validation import free_run_error
from .batches import split_episodes
from .config import TrainConfig
from .ensembles import member_configs, merge_members, open_run, train_groups, train_member
from .jobs import TrainJob, run_jobs
from .kinds import choice_joints, choice_options, choose_kinds, model_kind, prior_members
from .records import write_config

_log = logging.getLogger(__name__)

INPUT_MARGIN = 0.05
"""Relative margin by which the members that use the exogenous inputs must beat those that
ignore them on validation (overall, and no joint worse by more): a tie keeps the model that
cannot depend on them."""


def choose_inputs(use: Mapping[str, Any], ignore: Mapping[str, Any]) -> tuple[bool, str]:
    """Keep the inputs? From the two halves' validation free runs
    (:func:`~excavator_surrogate.surrogate.validation.free_run_error` results).

    Returns:
        ``(keep, reason)``, the reason one line with both scores.
    """
    m = INPUT_MARGIN
    worse = [
        j
        for j, (a, b) in enumerate(zip(use["theta_rmse"], ignore["theta_rmse"]))
        if not a <= (1 + m) * b  # NaN: worse
    ]
    better = use["val_error"] < (1 - m) * ignore["val_error"]
    keep = bool(better and not worse)
    why = (
        f"validation error {use['val_error']:.4g} with the inputs, {ignore['val_error']:.4g} "
        f"without: {'kept' if keep else 'ignored'}"
    )
    if not keep:
        why += (
            f" (joint(s) {worse} worse by more than {m:.0%})"
            if worse
            else f" (not better by {m:.0%})"
        )
    return keep, why


def train_choosing_inputs(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    show_progress: bool | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train ``cfg.members`` networks with the exogenous inputs used or ignored, whichever
    validates better (see the module docstring); returns ``OUT/best.pt``."""
    half = max(1, cfg.members // 2)
    n_prior = prior_members(cfg.members) if cfg.prior_choice else 0
    val_eps, out, workers = open_run(cfg, dataset, out, notes=notes, trainings=2 * half)
    names = list(dataset.spec.u_names[dataset.spec.n_joint :])
    _log.info(
        f"exogenous inputs {names}: {half} member(s) use them, {half} ignore them "
        f"(same seeds), {workers} in parallel; the better way trains the rest"
        + (f" and {n_prior} network(s) correcting the static map" if n_prior else "")
    )
    t0 = time.monotonic()
    ways = ("use", "ignore")
    base = replace(cfg, prior_choice=False, static_map=False)  # single networks
    cfgs = {w: member_configs(replace(base, exogenous=w))[:half] for w in ways}
    halves = train_groups(cfgs, dataset, out=out, workers=workers, show_progress=show_progress)
    vals = {
        w: free_run_error(merge(halves[w]), val_eps, max_steps=cfg.val_steps or None) for w in ways
    }
    keep, why = choose_inputs(vals["use"], vals["ignore"])
    way = "use" if keep else "ignore"
    _log.info(f"exogenous inputs {names}: {why}")
    for i in range(half):  # the winning half becomes the ensemble's first members
        os.replace(out / way / f"member_{i}", out / f"member_{i}")
    (out / way).rmdir()
    rest = member_configs(replace(base, exogenous=way))[half:]
    # the kind choice's map-correcting networks treat the inputs the chosen way too
    priors = (
        member_configs(replace(base, exogenous=way, prior=True, members=n_prior)) if n_prior else []
    )
    rest_jobs = [
        TrainJob(
            cfg=c, dataset=dataset, out=out / f"member_{half + i}", tag=f"exsur member {half + i}"
        )
        for i, c in enumerate(rest)
    ] + [
        TrainJob(cfg=c, dataset=dataset, out=out / "prior" / f"member_{i}", tag=f"exsur prior {i}")
        for i, c in enumerate(priors)
    ]
    more = run_jobs(
        train_member,
        rest_jobs,
        workers=min(workers, max(1, len(rest_jobs))),
        show_progress=show_progress,
    )
    record = {
        "inputs": names,
        "kept": keep,
        "why": why,
        "val_error_use": vals["use"]["val_error"],
        "val_error_ignore": vals["ignore"]["val_error"],
        "theta_rmse_use": vals["use"]["theta_rmse"],
        "theta_rmse_ignore": vals["ignore"]["theta_rmse"],
        "members_per_way": half,
    }
    training: dict[str, Any] = {"exogenous": record}
    lost = "ignore" if keep else "use"
    if any((m.metrics or {}).get("training", {}).get("budget_cut") for m in halves[lost]):
        training["budget_cut"] = True  # the choice itself depended on the clock: say so
    final_cfg = replace(cfg, exogenous=way)
    final_cfgs = cfgs[way] + rest
    nets = [load_checkpoint(p) for p in more]
    plains, prior_nets = halves[way] + nets[: len(rest)], nets[len(rest) :]
    model, column = None, ("exogenous", [c.exogenous for c in final_cfgs], way)
    if n_prior:  # the kinds, per joint, among the networks trained the chosen way
        joints = choice_joints(cfg, plains[0], split_episodes(cfg, dataset)[0], val_eps)
        model, kinds = choose_kinds(plains, prior_nets, val_eps, **joints, **choice_options(cfg))
        _log.info(f"two kinds of network: {kinds['why']}")
        training["kinds"] = kinds
        column = ("kind", ["plain"] * len(plains) + ["prior"] * len(prior_nets), model_kind(kinds))
    best = merge_members(
        final_cfg,
        final_cfgs + priors,
        plains + prior_nets,
        val_eps,
        out=out,
        t0=t0,
        training=training,
        merged=model,
        column=column,
    )
    chosen = {k: training[k] for k in ("exogenous", "kinds") if k in training}  # the records
    write_config(out, cfg, notes={**(notes or {}), **chosen})
    return best
