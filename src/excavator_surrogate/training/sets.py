"""The set rule: which of a choice's candidate joints change, judged on validation together.

Every choice the recipe makes after training (the static map per joint, :mod:`.map_joints`;
the kind of network per joint, :mod:`.kinds`) changes some joints of a model that others read:
a joint's angle is the input of the rest, so one joint's change moves the others'.  Each
choice therefore finds its candidate joints one by one, then tries them together and each
alone (:func:`best_set`) and keeps the set with the lowest validation error among those that
hurt no joint beyond what the whole gains (:func:`joint_allowance`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from ..data.episode import Episode
from ..surrogate.model import Surrogate
from ..surrogate.validation import free_run_error

SET_MARGIN = 0.05
"""A set of joints is kept when its validation error is at most this share above the base's
(the model without the change), overall and on every joint (the other joints read the changed
joints' angles), unless the whole gains more (:func:`joint_allowance`)."""


def joint_allowance(val_error: float, base_error: float) -> float:
    """How much worse than ``base`` [share] a joint's validation error may get in a kept set
    whose whole validation error is ``val_error`` against ``base_error``:

        allowance = max(SET_MARGIN, 1 - val_error / base_error)

    A set that lowers the whole error by 20 % may cost one joint up to 20 %, never more than
    the whole gains; one that gains less may cost a joint :data:`SET_MARGIN` at most.  (On the
    sessions case, the arm on the map lowered the whole validation error by 20 % and moved the
    bucket, which reads the arm's angle, 13 % worse; on 12 more test sessions the arm was
    24-29 % better and the bucket 2-7 % worse, over 3 seeds.  docs/real-history.md.)"""
    if not (math.isfinite(val_error) and math.isfinite(base_error) and base_error > 0):
        return SET_MARGIN  # nothing to share out (a perfect or failed base)
    return max(SET_MARGIN, 1.0 - val_error / base_error)


def best_set(
    cand: Sequence[bool],
    build: Callable[[list[bool]], Surrogate],
    base: Mapping[str, Any],
    val: Sequence[Episode],
    *,
    record: dict[str, Any],
    max_steps: int | None = None,
    known: Mapping[tuple[bool, ...], Mapping[str, Any]] | None = None,
    ignore: Sequence[bool] | None = None,
) -> tuple[Surrogate, dict[str, Any], list[bool]] | None:
    """The best set of joints to change, or None: the candidates ``cand`` together and each
    alone, each model ``build(joints)`` scored on the validation free run and kept if within
    :data:`SET_MARGIN` of ``base`` (a :func:`free_run_error` result) overall and within
    :func:`joint_allowance` of it on every joint (a joint's change moves the angles the others
    read).  ``known``: sets whose validation free run the caller has already scored (not run
    again).  ``ignore``: (n_joint,) joints that cannot refuse a set (another choice drives
    them whatever this one keeps): they still count in the whole error, which ranks the sets,
    but are not checked one by one.

    Returns:
        ``(model, its free_run_error, joints)`` of the lowest kept validation error; each set
        tried is appended to ``record["tried"]`` (``record["names"]``: the joints' names).
    """
    n_joint, names = len(cand), record["names"]
    skip = list(ignore) if ignore is not None else [False] * n_joint
    sets = [list(cand)]
    if sum(cand) > 1:
        sets += [[k == j for k in range(n_joint)] for j, c in enumerate(cand) if c]
    best: tuple[float, Surrogate, dict[str, Any], list[bool]] | None = None
    for joints in sets:
        model = build(joints)
        done = (known or {}).get(tuple(joints))
        got = (
            dict(done)
            if done is not None
            else free_run_error(model, list(val), max_steps=max_steps)
        )
        allow = joint_allowance(got["val_error"], base["val_error"])
        worse = [
            names[j]
            for j, (a, b) in enumerate(zip(got["theta_rmse"], base["theta_rmse"]))
            if not skip[j] and not a <= (1 + allow) * b
        ]
        ok = got["val_error"] <= (1 + SET_MARGIN) * base["val_error"] and not worse
        record["tried"].append(
            {
                "joints": [n for n, p in zip(names, joints) if p],
                "val_error": got["val_error"],
                "val_theta_rmse": got["theta_rmse"],
                "joint_allowance": allow,
                "kept": bool(ok),
            }
        )
        if ok and (best is None or got["val_error"] < best[0]):
            best = (got["val_error"], model, got, joints)
    return None if best is None else best[1:]
