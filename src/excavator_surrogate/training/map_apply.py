"""The static map choice applied to a run's checkpoint (:mod:`.map_joints` chooses; this
module rewrites ``best.pt`` and the records that follow from the choice).

``exsur train`` calls :func:`apply_map_choice` after training and merging, when ``[train]
static_map`` is set.  It writes the chosen model (or the same one) and its record
(``metrics.training.static_map``).  A joint on the map reads only its own command, so the
input choice's record (``metrics.training.exogenous``, the ``[exogenous]`` table of the
run's ``config.toml``) drops the joints the map now drives
(:func:`~.input_readers.drop_readers`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..data.episode import Episode
from ..surrogate.checkpoint import (
    checkpoint_dict,
    read_checkpoint,
    surrogate_from_dict,
    write_checkpoint_dict,
)
from .input_readers import drop_readers
from .map_joints import choose_map_joints
from .records import update_notes

_log = logging.getLogger(__name__)


def apply_map_choice(
    best: str | Path,
    train: Sequence[Episode],
    val: Sequence[Episode],
    *,
    config: str | Path | None = None,
    **options: Any,
) -> dict[str, Any]:
    """Run :func:`~.map_joints.choose_map_joints` on the checkpoint ``best`` and rewrite it
    atomically (the chosen model, or the same model; either way
    ``metrics.training.static_map`` records the choice).  Returns the record.

    The map reads no exogenous input, so a joint that follows it no longer reads the kept
    ones: ``metrics.training.exogenous`` drops it (:func:`~.input_readers.drop_readers`),
    and so does the ``[exogenous]`` table of ``config``, the run's ``config.toml``, if given
    and it has one.

    Args:
        best: the run's checkpoint; ``train``, ``val``: its training and validation episodes.
        config: the run's ``config.toml`` (None: no file to update).
        options: :func:`~.map_joints.choose_map_joints`'s keyword options
            (:func:`~.map_joints.map_options` gives a config's).
    """
    path = Path(best)
    ckpt = read_checkpoint(path)
    sur = surrogate_from_dict(ckpt, where=str(path))
    new, record = choose_map_joints(sur, train, val, **options)
    if new is not None:
        ckpt = checkpoint_dict(new, history=ckpt.get("history"))  # no resuming into it
    metrics = dict(ckpt.get("metrics") or {})
    training = dict(metrics.get("training") or {})
    training["static_map"] = record
    inputs = training.get("exogenous")  # the input choice's record, if the run made one
    off_map = dict(inputs) if isinstance(inputs, Mapping) else None
    by = "the static valve map, which ignores them, drives"
    if off_map is not None and drop_readers(off_map, record["chosen"], by=by):
        training["exogenous"] = off_map
    else:
        off_map = None
    metrics["training"] = training
    ckpt["metrics"] = metrics
    write_checkpoint_dict(path, ckpt)
    _log.info(f"{path}: static map: {record['why']}")
    if off_map is not None:
        _log.info(f"exogenous inputs {off_map.get('inputs')}: {off_map['why']}")
        if config is not None:
            update_notes(config, {"exogenous": off_map})
    return record
