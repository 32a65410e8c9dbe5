"""Every stage's config, built one way: preset table, then overrides.

:func:`stage_classes` names the config class of each preset table (``[run]``, ``[simulate]``,
``[clean]``, ``[train]``, ``[evaluate]``, ``[sweep]``); :func:`build_configs` builds them with
:func:`~excavator_surrogate.config.stage_config` from a loaded preset and the overrides of a
command (its ``--set SECTION.KEY=VALUE`` items merged with its named flags);
:func:`show_configs` prints the resolved tables with every field's documentation
(``exsur config show PRESET``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from .config import PresetConfig, describe_config, stage_config
from .errors import ConfigError


@dataclass(frozen=True)
class RunConfig(PresetConfig, table="run"):
    """The ``[run]`` table of a preset: which stages and baselines ``exsur run`` includes."""

    clean: bool = False
    """Run the cleaning stage and train on the cleaned data (Stage II presets)."""
    gru: bool = True
    """Also train the same-size GRU baseline for the comparison table."""
    arx: bool = True
    """Also fit the linear ARX baseline for the comparison table."""
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


def stage_classes() -> dict[str, type]:
    """Config class of each preset table, in pipeline order (imported on demand)."""
    from .clean.config import CleanConfig
    from .evaluate.cbe import EvaluateConfig
    from .scale.sweep import SweepConfig
    from .simulate.generate import SimulateConfig
    from .training import TrainConfig

    return {
        "run": RunConfig,
        "simulate": SimulateConfig,
        "clean": CleanConfig,
        "train": TrainConfig,
        "evaluate": EvaluateConfig,
        "sweep": SweepConfig,
    }


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
