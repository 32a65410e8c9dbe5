"""How big a network is before it is built, and whether it fits this machine's memory.

A typo such as ``hidden = 100000000`` (or a crafted checkpoint with ``hidden = 30000``) would
otherwise ask torch for terabytes and end in a traceback or the kernel's OOM killer.
:func:`n_param` counts the parameters of a :class:`~.model.ModelConfig` from its sizes alone;
:func:`check_fits` compares an estimate with :func:`available_memory` and refuses with one line
naming the knob.
"""

from __future__ import annotations

from ..errors import ConfigError, ExsurError
from ..memory import available_memory
from .model import CELL_GATES, ModelConfig


def n_param(cfg: ModelConfig) -> int:
    """Parameters of the network of ``cfg`` (recurrent layers, then the two-layer head).

    Python integers: no overflow for absurd sizes.
    """
    if cfg.cell == "arx":
        return (int(cfg.window) * int(cfg.n_feature) + 1) * int(cfg.n_joint)
    gates = CELL_GATES.get(cfg.cell, 4)
    h, f = int(cfg.hidden), int(cfg.head_hidden)
    n = 0
    for k in range(int(cfg.n_layer)):
        n_in = int(cfg.n_feature) if k == 0 else h
        n += gates * h * (n_in + h + 2)
    return n + f * (h + 1) + cfg.n_joint * (f + 1)


def human_bytes(n: float) -> str:
    """``n`` bytes as ``"1.2 GB"`` (powers of 1000, up to EB)."""
    units = ("B", "kB", "MB", "GB", "TB", "PB", "EB")
    k = 0
    while abs(n) >= 1000 and k < len(units) - 1:
        n /= 1000
        k += 1
    return f"{int(n)} B" if k == 0 else f"{n:.3g} {units[k]}"


def check_fits(
    n_bytes: int,
    *,
    what: str,
    fix: str,
    available: int | None = None,
    error: type[ExsurError] = ConfigError,
) -> None:
    """Refuse ``n_bytes`` that exceed the available memory.

    Args:
        n_bytes: the estimate [bytes].
        what: what needs it, e.g. ``"[train] hidden = 100000000: 4e17 parameters x 16 B"``.
        fix: what to do, e.g. ``"lower train.hidden"``.
        available: the budget [bytes] (default: :func:`available_memory`; unknown: no check).
        error: the error class raised (``CheckpointError`` for a stored network).

    Raises:
        ConfigError: (or ``error``) one line with the estimate and the available memory.
    """
    avail = available_memory() if available is None else available
    if avail is not None and n_bytes > avail:
        raise error(
            f"{what} needs about {human_bytes(n_bytes)} but {human_bytes(avail)} of memory is "
            f"available: {fix}"
        )
