"""Excitation: the signal kinds of :mod:`.signals` as one config and one ``generate`` call.

:class:`ExcitationConfig` (the ``[simulate.excitation]`` table, one sub-table per kind),
:data:`SIGNALS` (open-loop generators) and :data:`CLOSED_LOOP` (kinds run against the plant)
are derived from :data:`.signals.REGISTRY`; the signals themselves, the closed-loop
:class:`~.dig_operator.DigOperator` and the shared toolkit (:mod:`.commands`) live in their
own modules and are re-exported here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..spec import MachineSpec
from .commands import NominalModel, RngLike, VelocityMap, as_rng, clip_commands, fold_limits
from .dig_operator import DigCycleParams, DigOperator
from .signals import (
    REGISTRY,
    ChirpParams,
    MultisineParams,
    PrbsParams,
    Signal,
    StepParams,
    WorkCycleParams,
    chirp,
    multisine,
    prbs,
    steps,
    work_cycle,
)

__all__ = [
    "CLOSED_LOOP",
    "REGISTRY",
    "SIGNALS",
    "ChirpParams",
    "DigCycleParams",
    "DigOperator",
    "ExcitationConfig",
    "MultisineParams",
    "NominalModel",
    "PrbsParams",
    "RngLike",
    "Signal",
    "StepParams",
    "VelocityMap",
    "WorkCycleParams",
    "as_rng",
    "chirp",
    "clip_commands",
    "fold_limits",
    "generate",
    "multisine",
    "prbs",
    "steps",
    "work_cycle",
]

CLOSED_LOOP: tuple[str, ...] = tuple(k for k, s in REGISTRY.items() if s.generate is None)
"""Closed-loop signal kinds: run step by step against the plant (:class:`DigOperator`)."""

SIGNALS: dict[str, Signal] = {k: s.generate for k, s in REGISTRY.items() if s.generate}
"""Open-loop signal kinds by name."""

ExcitationConfig = dataclasses.make_dataclass(
    "ExcitationConfig",
    [(k, s.params, dataclasses.field(default_factory=s.params)) for k, s in REGISTRY.items()],
    frozen=True,
)
ExcitationConfig.__module__ = __name__  # picklable by name (simulation worker processes)
ExcitationConfig.__doc__ = (
    "Parameters of every signal kind (TOML table ``[simulate.excitation.<kind>]``); one field "
    "per kind of :data:`.signals.REGISTRY`."
)
ExcitationConfig.__field_docs__ = {  # type: ignore[attr-defined]
    k: f"Parameters of ``{k}``: {s.doc}." for k, s in REGISTRY.items()
}


def generate(
    kind: str,
    rng: RngLike,
    n_step: int,
    spec: MachineSpec,
    *,
    theta0: Sequence[float] | np.ndarray | None = None,
    omega_max: Sequence[float] | np.ndarray | None = None,
    limit_margin: float = 0.05,
    config: ExcitationConfig | None = None,
    velocity_map: VelocityMap | None = None,
) -> np.ndarray:
    """Generate ``u: (n_step, n_joint)`` of signal ``kind`` with its parameters from ``config``.

    ``velocity_map`` (optional) is the plant's nominal command -> velocity map used to keep
    the joints off their end stops (see :func:`fold_limits`); default: linear in ``omega_max``.
    Closed-loop kinds (:data:`CLOSED_LOOP`) need the plant and are run by
    :func:`~.generate.simulate_episode`.
    """
    if kind in CLOSED_LOOP:
        raise ConfigError(
            f"signal '{kind}' is a closed-loop operator script: it needs the plant's state "
            "(use simulate_dataset / DigOperator), not an open-loop command sequence"
        )
    if kind not in SIGNALS:
        raise ConfigError(f"unknown signal kind '{kind}': choose one of {', '.join(SIGNALS)}")
    if n_step < 1:
        raise ConfigError(f"n_step must be >= 1, got {n_step}")
    cfg = config or ExcitationConfig()
    params: Any = getattr(cfg, kind)
    return SIGNALS[kind](
        rng,
        n_step,
        spec,
        theta0=theta0,
        omega_max=omega_max,
        limit_margin=limit_margin,
        params=params,
        velocity_map=velocity_map,
    )
