"""Keep an exogenous input or not: the rule on validation that both ways of training the
choice share (:mod:`.variants`: networks trained only to decide it; :mod:`.dual`: every
network learns both ways).

The networks that use the inputs and those that ignore them (or the same networks run both
ways) are merged per way and scored by their validation free run; the inputs are kept
only if that way is better by :data:`INPUT_MARGIN` overall and no joint's angle RMSE is
worse by more (:func:`choose_inputs`).  Where the whole way is refused, the joints on which
it beats the other by the margin (:func:`input_joints`) are candidates to take the inputs
alone (:func:`choose_input_joints`): each seed's two networks become one, joint by joint
(:func:`paired`), and a set is kept under the same rule.  :func:`decide_inputs` runs both
steps and :func:`choice_record` is what ``metrics.training.exogenous`` and
``config.toml``'s ``[exogenous]`` record.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..data.dataset import Dataset
from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from ..surrogate.validation import free_run_error
from .batches import split_episodes
from .composite import plain_ensemble
from .config import TrainConfig
from .input_readers import drop_readers
from .kinds import map_pinned, spanned_joints

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


def input_joints(use: Mapping[str, Any], ignore: Mapping[str, Any]) -> list[bool]:
    """Per joint: does the half that uses the inputs beat the half that ignores them by
    :data:`INPUT_MARGIN` on its validation angle RMSE?  (A NaN is no.)"""
    m = INPUT_MARGIN
    return [bool(a < (1 - m) * b) for a, b in zip(use["theta_rmse"], ignore["theta_rmse"])]


def paired(
    use: Sequence[Surrogate], ignore: Sequence[Surrogate], joints: Sequence[bool]
) -> Surrogate:
    """The ensemble of the seeds' pairs: pair ``i`` is one network whose joint ``j`` is
    ``use[i]``'s where ``joints[j]``, else ``ignore[i]``'s (a composite,
    :func:`~excavator_surrogate.surrogate.ensemble.merge` with ``joint_weights``); the pairs
    are merged as the ensemble's members.

    Args:
        use, ignore: as many networks each, trained with the inputs used and ignored (pair
            ``i`` on the same seed).
        joints: (n_joint,) the joints that take the inputs.
    """
    return plain_ensemble(ignore, twins=use, twin_joints=joints)


def choose_input_joints(
    use: Sequence[Surrogate],
    ignore: Sequence[Surrogate],
    vals: Mapping[str, Mapping[str, Any]],
    val: Sequence[Any],
    *,
    max_steps: int | None = None,
    pinned: Sequence[bool] | None = None,
) -> tuple[list[bool] | None, list[dict[str, Any]]]:
    """The joints that take the inputs alone (see the module docstring), or None.

    Args:
        use, ignore: the two halves' networks (pair ``i`` on the same seed).
        vals: ``{"use": ..., "ignore": ...}``, each half's merged validation free run.
        val: the validation episodes.
        max_steps: validation free-run length cap.
        pinned: (n_joint,) joints the static map choice will drive whatever the networks
            (:func:`~.kinds.map_pinned`): no candidates, since their own gain would not last.

    Returns:
        ``(joints or None, tried)``: the kept set of lowest validation error, and one entry
        per set tried (its joints' names, validation error and angle RMSE, kept or not).
    """
    cand = input_joints(vals["use"], vals["ignore"])
    if pinned is not None:
        cand = [c and not p for c, p in zip(cand, pinned)]
    n_joint = len(cand)
    sets = [cand] if 0 < sum(cand) < n_joint else []  # all joints: the whole half, refused
    if sum(cand) > 1:
        sets += [[k == j for k in range(n_joint)] for j, c in enumerate(cand) if c]
    names = list(use[0].spec.names)
    tried: list[dict[str, Any]] = []
    best: tuple[float, list[bool]] | None = None
    for joints in sets:
        got = free_run_error(paired(use, ignore, joints), list(val), max_steps=max_steps)
        ok, _ = choose_inputs(got, vals["ignore"])
        tried.append(
            {
                "joints": [n for n, p in zip(names, joints) if p],
                "val_error": got["val_error"],
                "val_theta_rmse": got["theta_rmse"],
                "kept": ok,
            }
        )
        if ok and (best is None or got["val_error"] < best[0]):
            best = (got["val_error"], joints)
    return (None if best is None else best[1]), tried


def decide_inputs(
    cfg: TrainConfig,
    use: Sequence[Surrogate],
    ignore: Sequence[Surrogate],
    val_eps: list[Any],
    *,
    dataset: Dataset,
    n_prior: int,
    pairs: str,
    per_joint: bool = True,
    **extra: Any,
) -> tuple[dict[str, Any], bool, list[bool] | None, dict[str, Any]]:
    """The input choice on validation: the whole way (:func:`choose_inputs`), then, where it
    is refused, ``cfg.inputs_per_joint`` and ``per_joint`` allow and some joint is a
    candidate, the joints that take the inputs alone (:func:`choose_input_joints`).

    Args:
        use, ignore: networks with the inputs used and ignored (network ``i`` of each on the
            same seed, or the same network both ways).
        val_eps: the validation episodes; ``dataset``: the run's (its training split).
        n_prior: the kind choice's map-correcting networks (0: no kind choice).
        pairs, extra: for the record (:func:`choice_record`).

    Returns:
        ``(record, keep, joints, options)``: the choice's record (:func:`choice_record`),
        :func:`choose_inputs`'s verdict, :func:`choose_input_joints`'s joints (None where
        not tried), and the kind choice's per-joint options found on the way
        (``pinned``: :func:`~.kinds.map_pinned`, which the input choice reads too, and with
        ``n_prior`` ``spanned``: :func:`~.kinds.spanned_joints`; empty where not needed).
    """
    max_steps = cfg.val_steps or None
    vals = {
        "use": free_run_error(merge(list(use)), val_eps, max_steps=max_steps),
        "ignore": free_run_error(merge(list(ignore)), val_eps, max_steps=max_steps),
    }
    keep, why = choose_inputs(vals["use"], vals["ignore"])
    joints: list[bool] | None = None
    tried: list[dict[str, Any]] = []
    # the kind choice's options per joint, found once (they read the data and the networks'
    # window, spec and end stops only: the same for every network of the run)
    options: dict[str, Any] = {}
    # the pinned joints cost a map free run: only where some joint is a candidate at all
    if (
        not keep
        and cfg.inputs_per_joint
        and per_joint
        and any(input_joints(vals["use"], vals["ignore"]))
    ):
        train_eps = split_episodes(cfg, dataset)[0]
        carrier = ignore[0]
        # the input choice reads the pinned joints under either kind rule
        options = {"pinned": map_pinned(cfg, carrier, train_eps, val_eps)}
        if n_prior:
            options["spanned"] = spanned_joints(cfg, carrier.spec, train_eps, val_eps)
        joints, tried = choose_input_joints(
            use, ignore, vals, val_eps, max_steps=max_steps, pinned=options["pinned"]
        )
    spec = dataset.spec
    record = choice_record(
        spec.u_names[spec.n_joint :],
        spec.names,
        vals,
        keep=keep,
        why=why,
        joints=joints,
        tried=tried,
        pairs=pairs,
        **extra,
    )
    return record, keep, joints, options


def choice_record(
    names: Sequence[str],
    joint_names: Sequence[str],
    vals: Mapping[str, Mapping[str, Any]],
    *,
    keep: bool,
    why: str,
    joints: Sequence[bool] | None,
    tried: list[dict[str, Any]],
    pairs: str,
    **extra: Any,
) -> dict[str, Any]:
    """The input choice's record (``metrics.training.exogenous``, ``[exogenous]``).

    Args:
        names: the exogenous inputs; ``joint_names``: the machine's joints.
        vals: ``{"use": ..., "ignore": ...}``, each way's merged validation free run.
        keep: the inputs kept on every joint; ``why``: :func:`choose_inputs`'s reason.
        joints: (n_joint,) the joints that take them alone (:func:`choose_input_joints`), or
            None; ``tried``: its sets.
        pairs: what each joint-by-joint network is made of, for the reason.
        extra: more entries (how the ways were trained).
    """
    record = {
        "inputs": list(names),
        "kept": keep or joints is not None,
        "joints": list(joint_names) if keep else [],
        "per_joint": joints is not None,
        "why": why,
        "val_error_use": vals["use"]["val_error"],
        "val_error_ignore": vals["ignore"]["val_error"],
        "theta_rmse_use": vals["use"]["theta_rmse"],
        "theta_rmse_ignore": vals["ignore"]["theta_rmse"],
        **extra,
        "tried": tried,
    }
    if joints is not None:
        taken = [n for n, p in zip(joint_names, joints) if p]
        got = next(t for t in tried if t["joints"] == taken)
        record["joints"] = taken
        record["why"] = (
            f"{why}; {', '.join(taken)} take them alone: validation error "
            f"{got['val_error']:.4g} ({pairs} with and without them, joint by joint)"
        )
    return record


def inputs_after_kinds(record: dict[str, Any], kinds: Mapping[str, Any]) -> None:
    """Update the input choice's ``record`` in place after the kind choice (``kinds``, its
    record): a joint that the map-correcting networks, which ignore the inputs, drive alone
    (weight 1) no longer reads them; with none left the inputs are not ``kept``
    (:func:`~.input_readers.drop_readers`)."""
    alone = [n for n, w in zip(kinds["names"], kinds["weights"]) if w >= 1.0]
    drop_readers(record, alone, by="the map-correcting networks, which ignore them, drive")
