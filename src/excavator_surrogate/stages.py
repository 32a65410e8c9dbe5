"""Every stage's config, built one way: preset table, then overrides.

:func:`stage_classes` names the config class of each preset table (``[run]``, ``[simulate]``,
``[clean]``, ``[train]``, ``[evaluate]``, ``[sweep]``); :func:`build_configs` builds them with
:func:`~excavator_surrogate.config.stage_config` from a loaded preset and the overrides of a
command (its ``--set SECTION.KEY=VALUE`` items merged with its named flags);
:func:`show_configs` prints the resolved tables with every field's documentation
(``exsur config show PRESET``).
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from . import config as _config
from .config import RECORD_TABLES, PresetConfig, describe_config, stage_config
from .errors import ConfigError

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunConfig(PresetConfig, table="run"):
    """The ``[run]`` table of a preset: which stages and baselines ``exsur run`` includes."""

    clean: bool = False
    """Run the cleaning stage and train on the cleaned data (Stage II presets)."""
    gru: bool = True
    """Also train the same-size GRU baseline for the comparison table."""
    arx: bool = True
    """Also fit the linear ARX baseline for the comparison table."""
    structured: bool = True
    """Also fit the structured baseline (dead zone, gain, delay, end stops per joint) for the
    comparison table."""
    raw_baseline: bool = False
    """With ``clean``: also train on the raw (uncleaned) data, for the effect-of-cleaning table."""
    reference: Literal["measured", "true"] = "measured"
    """Main evaluation reference: recorded angles, or the ground truth (Stage II)."""
    paper_table: Literal["II", "III-noload", "III-compound", "none"] = "II"
    """Which of the paper's tables to show alongside."""
    fusion_figures: bool = True
    """With ``clean``: draw the Figure-3-style fusion plot per joint of the first test episode."""
    auto_train: bool = False
    """Choose the training config from the data (the recipe of ``exsur train DATASET`` without
    a preset); keys of the preset's ``[train]`` table override its choices."""


STAGE_NAMES = ("run", "simulate", "clean", "train", "evaluate", "sweep")
"""The preset tables, in pipeline order."""

RUN_SECTIONS = ("run", "simulate", "clean", "train", "evaluate")
"""The preset tables ``exsur run`` reads."""

DEFAULT_PRESET = "quick-hydraulic"
"""Preset of ``exsur run`` without ``--preset``: the README's 5-minute main job (``make demo``),
on the hydraulic stand-in, where the LSTM beats ARX."""


def stage_classes() -> dict[str, type]:
    """Config class of each preset table, in pipeline order (imported on demand)."""
    from .clean.config import CleanConfig
    from .evaluate.cbe import EvaluateConfig
    from .scale.sweep import SweepConfig
    from .simulate.config import SimulateConfig
    from .training import TrainConfig

    return {
        "run": RunConfig,
        "simulate": SimulateConfig,
        "clean": CleanConfig,
        "train": TrainConfig,
        "evaluate": EvaluateConfig,
        "sweep": SweepConfig,
    }


PRESET_KEYS = ("name", "extends")
"""Top-level keys of a preset besides its tables."""


def _sub_config(tp: Any) -> type | None:
    """The config dataclass of a field type (``X`` or ``X | None``), else None."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        subs = [a for a in typing.get_args(tp) if dataclasses.is_dataclass(a)]
        return subs[0] if subs else None
    return tp if isinstance(tp, type) and dataclasses.is_dataclass(tp) else None


def check_keys(cls: type, table: Mapping[str, Any], where: str, section: str) -> None:
    """Every key of ``table`` (the ``[section]`` table of ``where``) is a field of ``cls``,
    recursively through nested config tables (``[simulate.excitation.multisine]``).

    Raises:
        ConfigError: one line naming ``where``, the table, the key, its close match and the
            valid keys.
    """
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for key, value in table.items():
        if key not in names:
            close = difflib.get_close_matches(key, names, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise ConfigError(
                f"{where} [{section}]: unknown key(s) ['{key}'] for {cls.__name__}{hint}; "
                f"valid keys: {', '.join(names)}"
            )
        sub = _sub_config(hints[key])
        if sub is not None and isinstance(value, Mapping):
            check_keys(sub, value, where, f"{section}.{key}")


def check_preset(data: Mapping[str, Any], where: str) -> None:
    """Refuse an unknown table or key anywhere in one preset file (also tables the command does
    not read: ``[trian] epochs = 1`` is a typo, not a no-op).

    Raises:
        ConfigError: one line naming the file, the table or key, the close match and the valid
            names.
    """
    classes = stage_classes()
    for key, value in data.items():
        if key in PRESET_KEYS or key in RECORD_TABLES:
            continue
        if key not in classes:
            close = difflib.get_close_matches(key, list(classes), n=1)
            hint = f" (did you mean [{close[0]}]?)" if close else ""
            kind = "table" if isinstance(value, Mapping) else "key"
            shown = f"[{key}]" if kind == "table" else f"'{key}'"
            raise ConfigError(
                f"{where}: unknown {kind} {shown}{hint}; valid tables: "
                f"[{'], ['.join(classes)}] (top-level keys: {', '.join(PRESET_KEYS)})"
            )
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: [{key}] must be a table, got {value!r}")
        check_keys(classes[key], value, where, key)


def load_preset(name_or_path: str | Path) -> dict[str, Any]:
    """:func:`excavator_surrogate.config.load_preset` with every table and key of every file
    checked by :func:`check_preset` (the one loader of the commands)."""
    return _config.load_preset(name_or_path, check=check_preset)


def build_configs(
    preset: Mapping[str, Any],
    *,
    sections: Sequence[str] | None = None,
    overrides: Mapping[str, Mapping[str, Any]] | None = None,
    where: str = "",
) -> dict[str, Any]:
    """The configs of ``sections`` (default: every stage) from ``preset`` and ``overrides``.

    Raises:
        ConfigError: an override for a section that is not built, an unknown key or a bad value.
    """
    classes = stage_classes()
    names = list(sections) if sections is not None else list(classes)
    overrides = overrides or {}
    stray = sorted(set(overrides) - set(names))
    if stray:
        raise ConfigError(f"no [{stray[0]}] table here: settable tables are [{'], ['.join(names)}]")
    out = {}
    for name in names:
        if name in preset and not isinstance(preset[name], Mapping):
            raise ConfigError(f"{where} [{name}] must be a table".strip())
        out[name] = stage_config(
            classes[name], preset, name, overrides=overrides.get(name), where=where
        )
    return out


def _first_key(table: Mapping[str, Any], prefix: str) -> str:
    """``prefix.key[.sub...]`` of the first leaf of ``table`` (for messages)."""
    for k, v in table.items():
        return _first_key(v, f"{prefix}.{k}") if isinstance(v, Mapping) and v else f"{prefix}.{k}"
    return prefix


def check_sets_read(
    sets: Mapping[str, Any],
    cfgs: Mapping[str, Any],
    *,
    skipped: Mapping[str, str] | None = None,
) -> None:
    """Refuse a ``--set`` whose knob this command will not read: the user asked for something
    that will not happen (cleaning knobs without cleaning, simulate knobs with ``--data``,
    sensor knobs with ``simulate.sensors = false``, hydraulic knobs on the ideal plant).

    Args:
        sets: the ``--set`` items as tables (:func:`excavator_surrogate.config.parse_sets`).
        cfgs: the built configs of the command (the ``simulate`` one, if any, is inspected).
        skipped: tables the command does not read, each with the reason (e.g. ``{"clean":
            "this run does not clean (run.clean = false)"}``).

    Raises:
        ConfigError: one line naming the knob, why it is not read and what to do.
    """
    for section, why in (skipped or {}).items():
        if sets.get(section):
            key = _first_key(sets[section], section)
            raise ConfigError(f"--set {key}: not read, {why}; drop it")
    sim = cfgs.get("simulate")
    table = sets.get("simulate") or {}
    if sim is None or not isinstance(table, Mapping):
        return
    unread = {
        "sensor": (not sim.sensors, "simulate.sensors = false (add --set simulate.sensors=true)"),
        "hydraulics": (
            sim.plant != "hydraulic",
            f'simulate.plant = "{sim.plant}" (the hydraulic effects need plant = "hydraulic")',
        ),
    }
    for sub, (off, why) in unread.items():
        if off and table.get(sub):
            key = _first_key(table[sub], f"simulate.{sub}")
            raise ConfigError(f"--set {key}: not read, {why}; drop it")


SAMPLE_BYTES = 8 * 13
"""Bytes of one simulated sample in memory, a lower bound: float64 time, 4 commands, 4 angles,
4 velocities (the excavator; ground truth and flags add to it)."""
LONG_SIMULATION_MIN = 30.0
"""A simulation planned longer than this [min] is announced with its size before it starts."""
SAMPLES_PER_S = 5000.0
"""Simulated samples per second per worker, roughly (the hydraulic plant: 300k samples in
~17 s on 2 workers; closed-loop digging is slower) -- for the time in messages only."""


def check_dataset_size(sim: Any, *, out: str | Path) -> None:
    """Refuse a ``[simulate]`` config whose dataset cannot fit in memory (training loads it
    whole) or on the disk of ``out``, before simulating anything.

    Args:
        sim: the :class:`~excavator_surrogate.simulate.config.SimulateConfig`.
        out: the dataset folder (its nearest existing parent is where the files go).

    Raises:
        ConfigError: one line with the sample count, the bytes and time it needs, and the room.
    """
    import shutil

    from .surrogate.sizes import available_memory, human_bytes

    n = sum(
        int(getattr(sim, f"n_{s}")) * int(getattr(sim, f"steps_{s}"))
        for s in ("train", "val", "test")
    )
    need = n * SAMPLE_BYTES
    hours = n / (SAMPLES_PER_S * max(1, int(sim.workers))) / 3600
    base = Path(out).resolve()
    while not base.exists() and base != base.parent:
        base = base.parent
    try:
        disk: int | None = shutil.disk_usage(base).free
    except OSError:
        disk = None
    room = [(available_memory(), "memory"), (disk, f"free disk at {base}")]
    for have, what in room:
        if have is not None and need > have:
            raise ConfigError(
                f"[simulate] {n:.3g} samples (n_train x steps_train + val + test) need at least "
                f"{human_bytes(need)} and ~{hours:.3g} h to simulate, but {human_bytes(have)} of "
                f"{what} is available: lower simulate.n_train / simulate.steps_train"
            )
    if hours * 60 > LONG_SIMULATION_MIN:  # it fits, but a typo (an extra zero) would look so
        _log.warning(
            f"[simulate] {n:.3g} samples (n_train x steps_train + val + test) take ~{hours:.3g} h "
            f"on {max(1, int(sim.workers))} worker(s) and {human_bytes(need)} of memory to "
            "train on: interrupt (Ctrl-C, nothing is left) and lower simulate.n_train / "
            "simulate.steps_train if that is not what you meant"
        )


def show_configs(
    preset: Mapping[str, Any],
    *,
    sections: Sequence[str] | None = None,
    overrides: Mapping[str, Mapping[str, Any]] | None = None,
    where: str = "",
) -> str:
    """The resolved tables as commented TOML (every field with its one-line documentation)."""
    cfgs = build_configs(preset, sections=sections, overrides=overrides, where=where)
    return "\n".join(describe_config(name, cfg) for name, cfg in cfgs.items())
