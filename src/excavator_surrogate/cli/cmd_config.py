"""``exsur config show PRESET``: the resolved config of every stage, with each field's docs."""

from __future__ import annotations

import argparse

from .knobs import add_set_option, overrides


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``config`` subcommand (``config show``)."""
    from ..stages import STAGE_NAMES

    p = subparsers.add_parser(
        "config",
        help="show a preset's resolved configs with the documentation of every field",
        description="Print the configs a preset resolves to (defaults filled in, --set applied) "
        "as commented TOML: every knob of every stage, with its one-line documentation.",
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    s = sub.add_parser("show", help="print the resolved configs of PRESET")
    s.add_argument(
        "preset",
        nargs="?",
        default=None,
        metavar="PRESET",
        help="preset name or .toml path (default: the built-in defaults)",
    )
    s.add_argument(
        "--section",
        action="append",
        choices=STAGE_NAMES,
        default=None,
        help="only this table (repeatable; default: all)",
    )
    add_set_option(s, STAGE_NAMES)
    s.set_defaults(func=run, shows=True)  # -q does not mute what it was asked to show


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur config show``: prints the tables, returns 0."""
    from ..stages import STAGE_NAMES, load_preset, show_configs

    sections = args.section or list(STAGE_NAMES)
    if args.preset:
        _refuse_mapping(args.preset)
    preset = load_preset(args.preset) if args.preset else {}
    where = f"preset '{preset.get('name', args.preset)}'" if args.preset else ""
    over = overrides(args, STAGE_NAMES)
    over = {k: v for k, v in over.items() if k in sections}
    print(show_configs(preset, sections=sections, overrides=over, where=where), end="")
    return 0


def _refuse_mapping(name: str) -> None:
    """An import mapping (``[[joints]]``, ``[machine]``) is not a preset: say what it is."""
    import tomllib
    from pathlib import Path

    from ..errors import ConfigError

    path = Path(name)
    if not path.is_file():
        return
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return  # load_preset reports it
    if "joints" in data or "machine" in data:
        raise ConfigError(
            f"{path}: this is an import mapping, not a preset: use `exsur import LOGS "
            f"--mapping {path}` (docs/import.md)"
        )
