"""Which built-in MuJoCo plant a checkpoint belongs to: the one machine check shared by every
command that runs a checkpoint against ``ExcavatorMujoco-v0`` (``exsur compare``, ``exsur
control``, their Python helpers and ``examples/pi_controller.py``).

A trained checkpoint records where its training data came from in its machine spec
(``spec.meta["data_source"]``: ``mujoco-ideal``, ``mujoco-hydraulic``, ``import`` ...; see
:func:`excavator_surrogate.training.resume.with_source`).  :func:`checkpoint_plant`

1. refuses a checkpoint of another machine (other joints, periodic flags, command ranges,
   rate or exogenous inputs than the built-in excavator), in one line naming both;
2. refuses a checkpoint trained on data that did not come from a built-in plant (an
   imported machine, synthetic data), in one line naming both;
3. returns the plant the checkpoint was trained on when none is asked for, and refuses an
   explicit other plant (``--plant ideal`` for a hydraulic surrogate) in one line naming both.

Checkpoints written before the source was recorded fall back to the caller's default plant.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import CheckpointError, ConfigError
from ..simulate.config import SOURCES
from ..simulate.plant import PlantConfig
from ..spec import EXCAVATOR, MachineSpec
from ..surrogate.checkpoint import check_compatible
from ..training.resume import SOURCE_META

PLANTS: tuple[str, ...] = tuple(SOURCES)
"""The built-in plants of ``ExcavatorMujoco-v0``: ``ideal`` and ``hydraulic``."""
BUILT_IN = "the built-in MuJoCo excavator"
"""How messages name the machine of ``ExcavatorMujoco-v0``."""


def data_source(spec: MachineSpec) -> str | None:
    """The training data's source recorded in a checkpoint's spec, or None (not recorded)."""
    source = spec.meta.get(SOURCE_META)
    return str(source) if source else None


def trained_plant(spec: MachineSpec) -> str | None:
    """``ideal`` / ``hydraulic`` if the checkpoint was trained on that built-in plant's data
    only; None if its source is not recorded or is not a built-in plant."""
    by_source = {s: p for p, s in SOURCES.items()}
    return by_source.get(data_source(spec) or "")


def checkpoint_plant(
    spec: MachineSpec,
    plant: str | None = None,
    *,
    ckpt: str | Path,
    default: str = "ideal",
) -> str:
    """The built-in plant to run a checkpoint of machine ``spec`` against (see the module
    docstring).

    Args:
        spec: the checkpoint's machine spec (``Surrogate.spec``).
        plant: the plant asked for (``--plant``), or None for the checkpoint's.
        ckpt: the checkpoint, for messages.
        default: the plant of a checkpoint that does not record its source.

    Returns:
        ``"ideal"`` or ``"hydraulic"``.

    Raises:
        CheckpointError: another machine, data from elsewhere, or another plant than asked for.
        ConfigError: ``plant`` is not a built-in plant.
    """
    if plant is not None and plant not in PLANTS:
        raise ConfigError(f"plant must be one of {', '.join(PLANTS)}, got {plant!r}")
    check_compatible(
        spec, EXCAVATOR.with_rate(PlantConfig().rate_hz), ckpt=ckpt, data_name=BUILT_IN
    )
    source = data_source(spec)
    recorded = trained_plant(spec)
    if source is not None and recorded is None:
        raise CheckpointError(
            f"{ckpt}: the checkpoint was trained on '{source}' data of machine '{spec.name}', "
            f"not on {BUILT_IN} (sources {', '.join(SOURCES.values())}); running it against "
            "ExcavatorMujoco-v0 would compare two machines: use a checkpoint trained on "
            "'exsur simulate' data"
        )
    if recorded is None:
        return plant or default
    if plant is not None and plant != recorded:
        raise CheckpointError(
            f"{ckpt}: the checkpoint was trained on the {recorded} MuJoCo plant (data "
            f"'{source}'), not on the {plant} plant asked for; leave out the plant "
            f"(default: the checkpoint's) or use a checkpoint trained on '{SOURCES[plant]}' data"
        )
    return recorded
