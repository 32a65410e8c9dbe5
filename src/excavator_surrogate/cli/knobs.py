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
from collections.abc import Mapping, Sequence
from typing import Any

from ..config import load_preset, merge_tables, parse_sets


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
    from ..stages import build_configs

    name = preset if preset is not None else getattr(args, "preset", None)
    table = load_preset(name) if name else {}
    where = f"preset '{table.get('name', name)}'" if name else ""
    return build_configs(
        table, sections=sections, overrides=overrides(args, sections, named), where=where
    )
