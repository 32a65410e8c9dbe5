"""Which joints read a kept exogenous input, once a later choice has handed some joints to
a part of the model that ignores the inputs.

The input choice (:mod:`.input_choice`) records the joints that read the inputs
(``metrics.training.exogenous``, ``config.toml``'s ``[exogenous]``). Two choices run after
it and can take joints away from the networks that read them: the kind choice gives joints
to the map-correcting networks, which are trained without the inputs
(:func:`~.input_choice.inputs_after_kinds`), and the static map choice puts joints on the
valve map, which reads only its own joint's command (:func:`~.map_apply.apply_map_choice`).
The record has to say what the final model does. Otherwise the report would say "used by
the model" for a joint whose prediction cannot change with the input.

This module imports nothing from the training package, so both choices can use it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def drop_readers(record: dict[str, Any], alone: Sequence[str], *, by: str) -> bool:
    """Update the input choice's ``record`` in place: the joints ``alone`` are now driven by
    a part of the model that ignores the inputs, so they no longer read them.

    Args:
        record: the input choice's record (:func:`~.input_choice.choice_record`): its
            ``joints`` (the names of the joints that read the inputs), ``kept`` and ``why``.
        alone: the names of the joints that the blind part drives on its own.
        by: that part, for the reason line, e.g. ``"the static valve map, which ignores
            them, drives"``.

    Returns:
        Whether the record changed: some joint of ``alone`` read the inputs. If none did,
        the record is left as it was. Otherwise those joints leave ``joints``, their names
        are added to ``dropped``, ``kept`` is false when no joint is left, and ``why`` ends
        with who drives which joints and who still reads the inputs.
    """
    readers = list(record.get("joints") or [])
    gone = [n for n in readers if n in alone]
    if not gone:
        return False
    record["joints"] = [n for n in readers if n not in alone]
    record["dropped"] = [*(record.get("dropped") or []), *gone]
    record["kept"] = bool(record["joints"])
    left = record["joints"]
    record["why"] = f"{record.get('why', '')}; {by} {', '.join(alone)}" + (
        f": {', '.join(left)} read them" if left else ": no joint reads them"
    )
    return True
