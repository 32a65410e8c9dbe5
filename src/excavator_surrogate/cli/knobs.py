"""``--set SECTION.KEY=VALUE``: one option that reaches every field of a command's configs.

Every command that reads preset tables calls :func:`add_set_option` in ``register`` and
:func:`configs` in its handler; the named flags (``--epochs``, ``--seed`` ...) are shortcuts that
win over ``--set`` for the same field.  Values are TOML (``train.lr=3e-4``,
``train.play=[0.02,0.05]``, ``simulate.hydraulics.drift=false``); a bare word is a string
(``train.device=cuda``).  Every key goes through the strict config parser, so a typo is an error
naming the table and the valid keys.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from ..config import merge_tables, parse_sets
from ..errors import ConfigError


def add_set_option(p: argparse.ArgumentParser, sections: Sequence[str]) -> None:
    """Add the repeatable ``--set SECTION.KEY=VALUE`` option (for the tables ``sections``)."""
    p.add_argument(
        "--set",
        action="append",
        default=[],
        dest="sets",
        metavar="SECTION.KEY=VALUE",
        help=f"override any field of the [{'], ['.join(sections)}] table(s), e.g. "
        f"{sections[0]}.KEY=VALUE (repeatable; TOML values; named flags win; see "
        "'exsur config show PRESET')",
    )


def positive_seconds(option: str) -> Callable[[str], float]:
    """argparse ``type`` of the wall-time budget ``option`` (e.g. ``--max-seconds``): a finite
    number > 0 [s], or ``none`` (any case) for no budget (the config field's ``0``), else a
    one-line :class:`ConfigError`.

    0 and negatives are refused: the config field's ``0 = unlimited`` is not what
    ``--max-seconds 0`` reads as (leaving the option out keeps the preset's budget).
    """

    def parse(text: str) -> float:
        if text.strip().lower() == "none":
            return 0.0
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"invalid value: {text!r} (seconds, or none for no budget)"
            ) from None
        if not (math.isfinite(value) and value > 0):
            raise ConfigError(
                f"{option} {text}: give a finite number > 0 [s], or none for no time budget"
            )
        return value

    return parse


def overrides(
    args: argparse.Namespace,
    sections: Sequence[str],
    named: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, Any]:
    """``--set`` items of ``args`` as tables, with the ``named`` flags (None skipped) on top."""
    sets = parse_sets(getattr(args, "sets", None) or [], sections=sections)
    flags = {s: {k: v for k, v in t.items() if v is not None} for s, t in (named or {}).items()}
    return merge_tables(sets, flags)


def configs(
    args: argparse.Namespace,
    sections: Sequence[str],
    named: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    preset: str | None = None,
) -> dict[str, Any]:
    """The configs of ``sections`` from ``--preset`` (or ``preset``), ``--set`` and ``named``."""
    from ..stages import build_configs, load_preset

    name = preset if preset is not None else getattr(args, "preset", None)
    table = load_preset(name) if name else {}
    where = f"preset '{table.get('name', name)}'" if name else ""
    return build_configs(
        table, sections=sections, overrides=overrides(args, sections, named), where=where
    )
