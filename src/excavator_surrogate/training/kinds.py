"""Two kinds of network, chosen per joint: ``[train] prior_choice = true``.

A network trained from scratch and one that corrects the static valve map (``prior``: dead
zone, gain per direction, delay) generalise differently, and not alike on every joint: on
the stand-in sessions case the map-correcting networks drove the boom and the bucket better
on validation and on the test day, the plain ones the arm (docs/real-history.md).  With
``prior_choice`` the run trains the whole plain ensemble (``members`` networks, seeds
``seed, seed + 1, ...``, as without the option) and :func:`prior_members` more that
correct the map (seeds ``seed, seed + 1, ...``): ``members + prior_members(members)``
trainings, which the recipe plans the epochs for within the same budget
(:func:`~.auto.trainings`).  Both ensembles are scored by their validation free run, and:

1. a joint is a candidate for the map-correcting networks if their validation angle RMSE
   on it is below ``1 - margin`` times the plain ensemble's (``[train] prior_margin``,
   default :data:`PRIOR_MARGIN`: a near tie stays plain; a negative margin sends a near tie
   to the map-correcting networks);
2. for the candidates, and for each candidate alone, a **composite** ensemble is built
   (:func:`composite`): group ``g`` of every ``P``-th plain network and map-correcting
   network ``g`` becomes one network whose candidate joints come from the map-correcting
   network and the others from the mean of its plain ones
   (:func:`~excavator_surrogate.surrogate.ensemble.merge` with ``joint_weights``), and the
   ``P`` groups are merged into the ensemble.  A plain joint is then exactly the plain
   ensemble's mean, a map joint the map-correcting ensemble's;
3. the best set whose validation error is at most :data:`SET_MARGIN` above the plain
   ensemble's overall, and on every joint within the static map choice's allowance
   (:func:`~excavator_surrogate.training.map_joints.joint_allowance`), is kept (a joint's
   choice changes the angles the others read); if none, or no candidate, the plain ensemble
   is the model, as without the option.

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
from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from ..surrogate.prior import PRIOR_MAP
from ..surrogate.structured import with_map_joints
from ..surrogate.validation import free_run_error
from .config import TrainConfig
from .ensembles import member_configs, merge_members, open_run, train_groups
from .map_joints import SET_MARGIN, best_set
from .records import write_config

_log = logging.getLogger(__name__)

PRIOR_MARGIN = TrainConfig.prior_margin
"""Default relative margin by which the map-correcting networks must beat the plain ones on a
joint's validation angle RMSE for the joint to be a candidate (a tie stays plain);
``TrainConfig.prior_margin`` sets it."""

KINDS = ("plain", "prior")


def in_prior_form(plain: Surrogate, prior: Surrogate) -> Surrogate:
    """``plain`` (no map) as a network that reads ``prior``'s features and carries its map
    with zero gains: the same output, ready to be merged with ``prior``."""
    p = prior.net.prior
    n_joint = plain.spec.n_joint
    fit = {k: getattr(p, k).tolist() for k in PRIOR_MAP}  # no joint on it: gains 0
    return with_map_joints(plain, fit, [False] * n_joint, lags=prior.norm.lags or None)


def prior_members(members: int) -> int:
    """Map-correcting networks trained beside a plain ensemble of ``members``: the largest
    divisor of ``members`` up to half of it (4 -> 2, 8 -> 4, 6 -> 3; 1 for a prime), so
    that every group of :func:`composite` holds as many plain networks."""
    return max([p for p in range(1, members // 2 + 1) if members % p == 0], default=1)


def composite(
    plains: Sequence[Surrogate], priors: Sequence[Surrogate], use_prior: Sequence[bool]
) -> Surrogate:
    """The ensemble whose joints ``use_prior`` are the map-correcting networks' mean and the
    others the plain networks' mean.

    Args:
        plains: K plain networks; priors: P map-correcting networks, P dividing K.
        use_prior: (n_joint,) which joints the map-correcting networks drive.

    Returns:
        All plain or all map-correcting: that ensemble.  Else the merge of P composites,
        group ``g`` = plain networks ``g, g + P, ...`` (weight ``P / K`` each on the plain
        joints) and map-correcting network ``g`` (weight 1 on the others).
    """
    if not any(use_prior):
        return merge(list(plains))
    if all(use_prior):
        return merge(list(priors))
    n_prior = len(priors)
    if len(plains) % n_prior:
        raise ValueError(f"{len(priors)} map-correcting networks do not divide {len(plains)}")
    n_group = len(plains) // n_prior  # plain networks per group
    w_plain = [0.0 if p else 1.0 / n_group for p in use_prior]
    w_prior = [1.0 if p else 0.0 for p in use_prior]
    groups = [
        merge(
            [in_prior_form(a, b) for a in plains[g::n_prior]] + [b],
            joint_weights=[w_plain] * n_group + [w_prior],
            name=f"{b.name}-composite",
        )
        for g, b in enumerate(priors)
    ]
    return merge(groups)


def model_kind(record: Mapping[str, Any]) -> str:
    """What :func:`choose_kinds`'s ``record`` made the model: ``"plain"`` (no joint chosen),
    ``"prior"`` (every joint) or ``"composite"``."""
    chosen = len(record["chosen"])
    return "plain" if not chosen else "prior" if chosen == len(record["names"]) else "composite"


def choose_kinds(
    plains: Sequence[Surrogate],
    priors: Sequence[Surrogate],
    val: Sequence[Any],
    *,
    max_steps: int | None = None,
    margin: float = PRIOR_MARGIN,
) -> tuple[Surrogate, dict[str, Any]]:
    """The model of the two ensembles (see the module docstring) and the record of the choice.

    Args:
        plains: the K plain networks; priors: the P map-correcting ones (P divides K).
        val: the validation episodes.
        max_steps: validation free-run length cap (as the epoch selection's).
        margin: a joint is a candidate for the map-correcting networks when their
            validation angle RMSE is below ``1 - margin`` times the plain ensemble's.

    Returns:
        ``(model, record)``; ``record`` holds both ensembles' validation scores, the
        candidate joints, the sets tried and what was chosen, with a one-line ``why``.
    """
    names = list(plains[0].spec.names)
    merged = {"plain": merge(list(plains)), "prior": merge(list(priors))}
    vals = {k: free_run_error(m, list(val), max_steps=max_steps) for k, m in merged.items()}
    base = vals["plain"]
    cand = [
        bool(b < (1 - margin) * a) for a, b in zip(base["theta_rmse"], vals["prior"]["theta_rmse"])
    ]
    record: dict[str, Any] = {
        "names": names,
        "val_theta_rmse_plain": base["theta_rmse"],
        "val_theta_rmse_prior": vals["prior"]["theta_rmse"],
        "val_error_plain": base["val_error"],
        "val_error_prior": vals["prior"]["val_error"],
        "candidates": [n for n, c in zip(names, cand) if c],
        "margin": margin,
        "tried": [],
        "chosen": [],
    }
    if not any(cand):
        record["why"] = (
            f"the map-correcting networks are not below {1 - margin:.0%} of the plain ones' "
            "validation angle RMSE on any joint: the plain networks drive every joint"
        )
        return merged["plain"], record
    build = partial(composite, plains, priors)  # joints -> the composite taking them
    every = (True,) * len(names)  # that set is the map-correcting ensemble: scored above
    best = best_set(
        cand, build, base, val, record=record, max_steps=max_steps, known={every: vals["prior"]}
    )
    if best is None:
        record["why"] = (
            f"every set of joints on the map-correcting networks is worse than the plain "
            f"networks' validation error {base['val_error']:.4g} by more than "
            f"{SET_MARGIN:.0%} overall, or on a joint by more than the whole gains: the plain "
            "networks drive every joint"
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
    """Train the plain ensemble of ``cfg.members`` networks and :func:`prior_members` more
    that correct the static map, and keep per joint the kind that validates better (see the
    module docstring); returns ``OUT/best.pt``."""
    n_plain, n_prior = cfg.members, prior_members(cfg.members)
    val_eps, out, workers = open_run(cfg, dataset, out, notes=notes, trainings=n_plain + n_prior)
    _log.info(
        f"two kinds of network: {n_plain} plain and {n_prior} correcting the static map (seeds "
        f"from {cfg.seed}), {workers} in parallel; per joint, the kind that validates better"
    )
    t0 = time.monotonic()
    # the members are single networks: the static map choice runs on the model they make
    base = replace(cfg, prior_choice=False, static_map=False)
    cfgs = {
        "plain": member_configs(base),
        "prior": member_configs(replace(base, prior=True, members=n_prior)),
    }
    nets = train_groups(cfgs, dataset, out=out, workers=workers, show_progress=show_progress)
    model, record = choose_kinds(
        nets["plain"],
        nets["prior"],
        val_eps,
        max_steps=cfg.val_steps or None,
        margin=cfg.prior_margin,
    )
    _log.info(f"two kinds of network: {record['why']}")
    kind = model_kind(record)
    best = merge_members(
        cfg,
        cfgs["plain"] + cfgs["prior"],
        nets["plain"] + nets["prior"],
        val_eps,
        out=out,
        t0=t0,
        training={"kinds": record},
        merged=model,
        column=("kind", [k for k in KINDS for _ in cfgs[k]], kind),
    )
    write_config(out, cfg, notes={**(notes or {}), "kinds": record})
    return best
