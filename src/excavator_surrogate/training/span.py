"""How much of the training's command range the validation split exercises, per joint.

A choice made on validation holds where validation tested it.  The recipe chooses on the
validation free run between the networks and simpler structures: the static valve map
(:mod:`.map_joints`) and the networks that correct it (:mod:`.kinds`).  A valve's speed is
not linear in its command (it saturates), so a map that fits one command level can miss
another by a factor of two.  When validation commands a joint only over a small part of the
range the training commanded it (h1-dev's validation runs all sit at 50 % duty, a little
beyond the dead zone), its free run shows how each structure does there and nothing of the
rest: there the map of h1-dev's boom validated as well as the networks, and free-ran a
held-out 80 % duty 3x worse (docs/real-history.md).

:func:`command_span` measures it per joint and direction of motion, beyond the static map's
dead zone ``[a_neg, a_pos]`` (:func:`~excavator_surrogate.surrogate.structured.fit_joints`,
undelayed, as ``fit_prior``'s): with ``q_train`` and ``q_val`` the :data:`SPAN_PERCENTILE` th
percentile of the commands beyond the edge ``a`` in that direction,

    span_dir = (q_val - a) / (q_train - a)      (1 where training never commands that way)
    span     = min over the two directions

and :func:`joint_spans` keeps the joints whose span reaches ``[train] choice_min_span``.
Only those can leave the plain networks on validation's word; elsewhere the plain networks
drive the joint, as they do where no choice is made.  On the development operator logs
every joint spans at least 0.69 of its range; on h1-dev 0.19-0.31.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..data.episode import Episode
from ..spec import MachineSpec
from ..surrogate.structured import fit_joints

SPAN_PERCENTILE = 99.0
"""Percentile of a direction's commands beyond the dead zone that stands for its extent (the
largest command but for the few odd samples)."""


def command_span(
    train: Sequence[Episode], val: Sequence[Episode], spec: MachineSpec
) -> list[float]:
    """Per joint, the share of the training's command range beyond the dead zone that the
    validation commands reach, in the direction that reaches less (see the module docstring).

    Args:
        train: training episodes (``u: (n_step, n_u)``; joint ``j``'s command is column ``j``).
        val: validation episodes.
        spec: the machine spec.

    Returns:
        (n_joint,) spans >= 0: 0 where validation never commands the joint beyond its dead
        zone in a direction the training does; 1 where the training never commands it
        beyond its dead zone at all.
    """
    fits = fit_joints(train, spec, max_delay=0)  # the dead zones only: no gain spread
    spans = []
    for j in range(spec.n_joint):
        u_train = np.concatenate([e.u[:, j] for e in train])
        u_val = np.concatenate([e.u[:, j] for e in val]) if val else np.zeros(0)
        span = 1.0
        for sign, edge in ((1.0, fits[j].a_pos), (-1.0, -fits[j].a_neg)):
            t = sign * u_train[np.isfinite(u_train)]
            v = sign * u_val[np.isfinite(u_val)]
            t, v = t[t > edge], v[v > edge]
            if t.size == 0:  # the training never drives it this way: nothing to cover
                continue
            # span_dir = (q_val - a) / (q_train - a); span = min over the directions
            reach = float(np.percentile(t, SPAN_PERCENTILE)) - edge
            got = float(np.percentile(v, SPAN_PERCENTILE)) - edge if v.size else 0.0
            span = min(span, got / reach) if reach > 0 else span
        spans.append(max(0.0, span))
    return spans


def joint_spans(
    train: Sequence[Episode], val: Sequence[Episode], spec: MachineSpec, *, min_span: float
) -> tuple[list[float] | None, list[bool]]:
    """``(spans, spanned)``: :func:`command_span` per joint, and whether validation commands
    each over at least ``min_span`` of the training's command range (with ``min_span = 0``:
    ``(None, all True)``, not computed)."""
    if min_span <= 0:
        return None, [True] * spec.n_joint
    spans = command_span(train, val, spec)
    return spans, [s >= min_span for s in spans]


def span_note(spans: Sequence[float], spec: MachineSpec, *, min_span: float) -> str:
    """One line naming the joints below ``min_span`` and their spans, e.g. ``"boom 24 %, arm
    22 %"`` (empty if none)."""
    return ", ".join(
        f"{js.name} {100 * s:.0f} %" for js, s in zip(spec.joints, spans) if s < min_span
    )
