"""Typed, frozen configs and TOML presets.

Each pipeline stage has one frozen dataclass config (``SimulateConfig``, ``CleanConfig``,
``TrainConfig`` ...), every field with a type, a default and a one-line docstring.
A preset is a TOML file shipped in ``excavator_surrogate/presets/<name>.toml`` with one
table per stage::

    [simulate]
    n_train = 12
    [train]
    epochs = 30

:func:`load_preset` reads it; :func:`from_dict` builds a config from one table and rejects
unknown keys with a one-line error; :func:`to_dict` turns a config back into plain data, so
every output folder can record the config that produced it (``config.toml``).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import itertools
import math
import re
import tomllib
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

import tomli_w

from .errors import ConfigError

C = TypeVar("C")


def preset_names() -> list[str]:
    """Names of the presets shipped with the package."""
    root = resources.files("excavator_surrogate") / "presets"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


PresetCheck = Callable[[Mapping[str, Any], str], None]
"""``check(tables, where)``: raises :class:`ConfigError` on an unknown table or key of one file."""


class Preset(dict[str, Any]):
    """A loaded preset: the nested tables, and where each of their keys was written.

    ``origins`` maps ``"section.key"`` to the file that set it last (a path, or ``preset
    'name'`` for a shipped one), through every ``extends``, so that a bad value's error can
    name the file to edit (:func:`stage_config`).  A plain dict in its place has no origins.
    """

    origins: dict[str, str]

    def __init__(self, *args: Any, origins: Mapping[str, str] | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.origins = dict(origins or {})


def load_preset(name_or_path: str | Path, *, check: PresetCheck | None = None) -> Preset:
    """Load a preset by name (shipped) or by path to a TOML file.

    Returns the raw nested dict (one table per stage) as a :class:`Preset`, which also records
    the file of every key.  A preset may ``extends = "other"`` another preset; tables are
    merged key by key.  ``check`` is applied to every file's own tables (the preset and each
    one it extends), so an error names the file with the typo
    (:func:`excavator_surrogate.stages.load_preset` checks every table and key).
    """
    p = Path(str(name_or_path))
    if p.suffix == ".toml" or p.is_file():
        if not p.exists():
            raise ConfigError(
                f"{p}: preset file not found (give a shipped name: {', '.join(preset_names())})"
            )
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError as e:  # a Parquet episode or checkpoint given as --preset
            raise ConfigError(f"{p}: not a TOML text file (not UTF-8: {e.reason})") from e
        where = str(p)
    else:
        res = resources.files("excavator_surrogate") / "presets" / f"{name_or_path}.toml"
        if not res.is_file():
            raise ConfigError(
                f"unknown preset '{name_or_path}': choose one of {', '.join(preset_names())} or a .toml path"
            )
        text = res.read_text(encoding="utf-8")
        where = f"preset '{name_or_path}'"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{where}: invalid TOML ({e})") from e
    if check is not None:
        check(data, where)
    base = data.pop("extends", None)
    own_name = data.get(
        "name", Path(str(name_or_path)).stem if p.suffix == ".toml" else str(name_or_path)
    )
    merged = Preset() if base is None else load_preset(base, check=check)
    for k, v in data.items():
        if isinstance(v, dict):
            merged.origins.update({f"{k}.{key}": where for key in v})
            if isinstance(merged.get(k), dict):
                v = {**merged[k], **v}
        merged[k] = v
    merged["name"] = own_name
    return merged


RECORD_TABLES = ("data", "logs", "recipe", "kinds", "exogenous", "command", "resume", "parallel")
"""Entries exsur writes into an output's ``config.toml`` besides the preset tables: where the
data came from, what a run chose and why (``[recipe]``, ``[kinds]``, ``[exogenous]``), and
the command's own arguments that no preset table holds (``[command]``: its name, input
paths and options, e.g. ``exsur evaluate``'s checkpoint and ``--compare`` entries), the
checkpoint a resumed training continued (``[resume]``: ``from``, ``epoch``), and the
processes of a data-parallel training (``[parallel]``: ``world_size``, the per-process batch
and the global one).
A record read back as a preset skips them; a writer of another entry must add it here, or
its record would not load back (``training.records.write_config`` checks)."""


CAP_OPTIONS = (
    "--max-seconds of exsur train, --max-train-seconds of exsur run, --trial-seconds of exsur sweep"
)
"""The options that set the wall-time cap (``max_train_seconds``), by command: a message
about a cut names them all, as training does not know which command runs it."""


INF_OK = frozenset({"tau_jump", "tau_cons", "max_untrusted_s"})
"""Config fields where ``inf`` means "off" (a threshold never reached); NaN is never accepted."""


def _coerce(tp: Any, value: Any, where: str, allow_inf: bool = False) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errs = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(a, value, where, allow_inf)
            except ConfigError as e:
                errs.append(str(e))
        raise ConfigError(errs[0] if errs else f"{where}: bad value {value!r}")
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, where, allow_inf) for v in value)
        if len(args) != len(value):
            raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(a, v, where, allow_inf) for a, v in zip(args, value))
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return dict(value)
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}: must be one of {list(args)}, got {value!r}")
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return from_dict(tp, value, where=where)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if math.isnan(value) or (math.isinf(value) and not allow_inf):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type[C], data: dict[str, Any] | None, *, where: str = "config") -> C:
    """Build frozen dataclass ``cls`` from ``data``; unknown keys are an error."""
    data = dict(data or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        close = difflib.get_close_matches(unknown[0], list(fields), n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise ConfigError(
            f"{where}: unknown key(s) {unknown} for {cls.__name__}{hint}; "
            f"valid keys: {sorted(fields)}"
        )
    kwargs = {k: _coerce(hints[k], v, f"{where}.{k}", k in INF_OK) for k, v in data.items()}
    return cls(**kwargs)


def to_dict(cfg: Any) -> dict[str, Any]:
    """Plain-data form of a (nested) config dataclass, tuples as lists, None dropped (TOML has no null).

    The fields a config names in its optional ``unread_fields()`` (``TrainConfig``: the other
    mode's knobs, which must keep their defaults) are dropped too, as the strict check of a
    preset table (``TrainConfig.adapt_table``) refuses them even at their defaults: a
    ``config.toml`` written from this form loads back as a preset to the same config.
    """

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            unread = set(v.unread_fields()) if hasattr(v, "unread_fields") else set()
            return {
                f.name: conv(getattr(v, f.name))
                for f in dataclasses.fields(v)
                if getattr(v, f.name) is not None and f.name not in unread
            }
        if isinstance(v, tuple | list):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items() if x is not None}
        if isinstance(v, Path):
            return str(v)
        return v

    return conv(cfg)


def toml_value(v: Any) -> str:
    """One TOML value on one line (scalar, array or inline table), for the commented lines
    of :func:`describe_config`.

    tomli-w formats every scalar and key (escapes, floats, ``inf``); only the one-line joining
    of arrays and inline tables is done here, because tomli-w writes arrays over several lines,
    which a commented-out ``# key = value`` line cannot hold.

    Raises:
        TypeError: a value TOML cannot hold (``None``, a ``Path``: convert with :func:`to_dict`).
    """
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        items = (f"{tomli_w.dumps({str(k): 0})[:-5]} = {toml_value(x)}" for k, x in v.items())
        return "{ " + ", ".join(items) + " }"
    return tomli_w.dumps({"v": v})[4:-1]


def dumps_toml(tables: Mapping[str, Any]) -> str:
    """A config record (``config.toml``) as TOML text, written by tomli-w: scalars first,
    then one ``[table]`` per nested dict.

    Raises:
        TypeError: a value TOML cannot hold (``None``, a ``Path``: convert with :func:`to_dict`).
    """
    return tomli_w.dumps(dict(tables))


def record_text(path: str | Path, tables: Mapping[str, Any]) -> str:
    """The ``config.toml`` record of a command that writes INTO folder ``path``'s
    ``config.toml`` (``exsur evaluate``): ``tables`` replace the file's own, and the tables
    of another command that wrote the folder (a training's ``[train]``) are kept."""
    try:
        old = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        old = {}  # none yet, or not a record: the new one alone
    return dumps_toml({**old, **tables})


def parse_sets(items: Sequence[str], *, sections: Sequence[str] | None = None) -> dict[str, Any]:
    """``["train.lr=3e-4", "simulate.hydraulics.drift=false"]`` as nested tables.

    Values are TOML (``3e-4``, ``true``, ``[0.02, 0.05]``, ``"cpu"``); a bare word that is not
    TOML is taken as a string (``train.device=cuda``).  With ``sections``, a key outside them is
    an error (``exsur train`` reads only ``[train]``).

    Raises:
        ConfigError: an item without ``SECTION.KEY=VALUE`` or outside ``sections``.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        path = key.strip().split(".")
        if not sep or len(path) < 2 or not all(path):
            raise ConfigError(f"--set {item!r}: expected SECTION.KEY=VALUE, e.g. train.lr=3e-4")
        if sections is not None and path[0] not in sections:
            raise ConfigError(f"--set {item!r}: this command reads only [{'], ['.join(sections)}]")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = text.strip()
        node = out
        for i, part in enumerate(path[:-1]):
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                above = ".".join(path[: i + 1])
                raise ConfigError(
                    f"--set {item!r}: an earlier --set gave {above} a value, so it cannot hold "
                    "keys; keep one of the two"
                )
        node[path[-1]] = value
    return out


def merge_tables(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``over`` merged in key by key (nested tables merged, not replaced)."""
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge_tables(out[k], v)
        else:
            out[k] = v
    return out


def stage_config(
    cls: type[C],
    preset: Mapping[str, Any],
    section: str,
    *,
    overrides: Mapping[str, Any] | None = None,
    where: str = "",
) -> C:
    """The one way a stage's config is built: ``preset[section]``, then ``overrides``.

    ``overrides`` are the command's ``--set SECTION.KEY=VALUE`` table for this section and its
    named flags (None values skipped; nested tables merged).  Every key goes through the strict
    :func:`from_dict`.  A class may define ``adapt_table(table, *, changed)`` to drop knobs that
    an override makes meaningless (``TrainConfig``: the other mode's knobs when ``mode`` changes).

    Raises:
        ConfigError: unknown key or bad value, naming ``where [section].key`` and, where
            ``preset`` is a :class:`Preset`, the file that set it (:func:`origin_hint`).
    """
    over = {k: v for k, v in (overrides or {}).items() if v is not None}
    table = merge_tables(dict(preset.get(section) or {}), over)
    try:
        adapt = getattr(cls, "adapt_table", None)
        if adapt is not None:
            table = adapt(table, changed=set(over))
        return from_dict(cls, table, where=f"{where} [{section}]".strip())
    except ConfigError as e:
        origins = getattr(preset, "origins", {})
        raise ConfigError(f"{e}{origin_hint(str(e), section, table, over, origins)}") from e


_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
OVERRIDE = "--set or a flag"
"""Where :func:`origin_hint` says a key came from when the command, not a file, set it."""


def origin_hint(
    message: str,
    section: str,
    table: Mapping[str, Any],
    overrides: Mapping[str, Any],
    origins: Mapping[str, str],
) -> str:
    """Where the keys a config error names were written: ``" (train.epochs: from b.toml)"``.

    The keys are those of ``table`` (the ``[section]`` table as built) that the message names;
    each one's source is ``overrides`` if it is there, else its file in ``origins``
    (:attr:`Preset.origins`), and keys of one source are listed together.  A message that
    names none of them (a check across keys) gets the sources of the whole table.  Empty when
    no source is known (a plain dict, every key at its default).
    """

    def source(key: str) -> str | None:
        return OVERRIDE if key in overrides else origins.get(f"{section}.{key}")

    named = [k for k in dict.fromkeys(_NAME.findall(message)) if k in table and source(k)]
    if not named:
        sources = list(dict.fromkeys(s for k in table if (s := source(k)) is not None))
        return f" ([{section}]: from {' and '.join(sources)})" if sources else ""
    by_source: dict[str, list[str]] = {}
    for k in named:
        by_source.setdefault(str(source(k)), []).append(f"{section}.{k}")
    return " (" + "; ".join(f"{', '.join(ks)}: from {s}" for s, ks in by_source.items()) + ")"


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def check_types(cfg: Any, where: str) -> None:
    """Refuse a field of dataclass ``cfg`` whose value is not of its declared type, with the
    line :meth:`PresetConfig.from_preset` gives for the same value (``[train].epochs:
    expected an integer, got '3'``; ``where``: ``"[train]"``).  Call it first in a config's
    ``__post_init__``: a config built directly then fails in one line, not in a comparison
    of its own checks.  NumPy scalars count as the Python numbers they hold; a NaN or
    infinite float and a ``Literal`` field are left to the config's own value checks.

    Raises:
        ConfigError: the first field of the wrong type.
    """
    hints = _hints(type(cfg))
    for f in dataclasses.fields(cfg):
        tp, v = hints[f.name], getattr(cfg, f.name)
        if hasattr(v, "item") and hasattr(v, "dtype") and getattr(v, "ndim", 1) == 0:
            v = v.item()  # a NumPy scalar (the recipe's arithmetic)
        if typing.get_origin(tp) is typing.Literal or (
            isinstance(v, float) and not math.isfinite(v)
        ):
            continue
        _coerce(tp, v, f"{where}.{f.name}", allow_inf=True)


def need_config(cfg: Any, cls: type[C]) -> C:
    """``cfg``, if it is a ``cls`` (an entry point's config argument).

    Raises:
        ConfigError: one line naming the class needed, how to build one, and the type given
            (a dict of options is not a config).
    """
    if isinstance(cfg, cls):
        return cfg
    name = cls.__name__
    raise ConfigError(
        f"cfg: a {name} is needed, got {type(cfg).__name__}; build one with "
        f"{name}.from_preset('tiny', key=value, ...) or {name}(key=value, ...)"
    )


class PresetConfig:
    """Base of the stage configs: ``Config.from_preset(preset, **overrides)`` on every stage.

    A config names its preset table in its class statement
    (``class SimulateConfig(PresetConfig, table="simulate")``); it adds no field.
    """

    preset_table: typing.ClassVar[str] = ""
    """The preset table this config is read from (``"simulate"``)."""

    def __init_subclass__(cls, *, table: str = "", **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if table:
            cls.preset_table = table

    @classmethod
    def from_preset(cls, preset: str | Path | Mapping[str, Any], **overrides: Any) -> typing.Self:
        """The config of a preset's table, then ``overrides`` (None values skipped).

        Args:
            preset: a shipped preset's name (``"tiny"``), a TOML file, or a loaded preset
                (:func:`load_preset`).
            **overrides: field values that replace the preset's (``epochs=5``).

        Raises:
            ConfigError: unknown preset, or an unknown key or bad value in the table or the
                overrides (one line naming ``[table].key``).
        """
        tables = preset if isinstance(preset, Mapping) else load_preset(preset)
        where = "" if isinstance(preset, Mapping) else str(preset)
        return stage_config(cls, tables, cls.preset_table, overrides=overrides, where=where)


def field_docs(cls: type) -> dict[str, str]:
    """The one-line docstrings under the fields of dataclass ``cls`` (first line of each)."""
    import ast
    import inspect
    import textwrap

    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        docs.update(vars(klass).get("__field_docs__", {}))  # generated dataclasses
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for a, b in itertools.pairwise(body):
            if (
                isinstance(a, ast.AnnAssign)
                and isinstance(a.target, ast.Name)
                and isinstance(b, ast.Expr)
                and isinstance(b.value, ast.Constant)
                and isinstance(b.value.value, str)
            ):
                docs[a.target.id] = " ".join(b.value.value.split())
    return docs


def describe_config(section: str, cfg: Any, *, doc: str | None = None) -> str:
    """``cfg`` as a TOML table ``[section]`` with each field's docstring as a comment above it
    (nested config dataclasses as sub-tables; ``None`` fields, and the fields named by the
    config's optional ``unread_fields()``, as commented-out lines)."""
    import textwrap

    docs = field_docs(type(cfg))
    unread = set(cfg.unread_fields()) if hasattr(cfg, "unread_fields") else set()
    lines = [] if not doc else textwrap.wrap(doc, 98, initial_indent="# ", subsequent_indent="# ")
    lines.append(f"[{section}]")
    subs = []
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            subs.append((f"{section}.{f.name}", v, docs.get(f.name)))
            continue
        doc = docs.get(f.name)
        if doc:
            lines += textwrap.wrap(doc, 98, initial_indent="# ", subsequent_indent="# ")
        plain = to_dict({"v": v}).get("v")
        if f.name in unread:
            lines.append(f"# {f.name} = {toml_value(plain)}  (not read in this configuration)")
        elif plain is None:
            lines.append(f"# {f.name} = (unset)")
        else:
            lines.append(f"{f.name} = {toml_value(plain)}")
    text = "\n".join(lines) + "\n"
    for name, sub, sub_doc in subs:
        text += "\n" + describe_config(name, sub, doc=sub_doc)
    return text
