"""The prediction-horizon figure of ``exsur evaluate``: angle RMSE against the horizon after
a measured start, one panel per joint, each model against the hold baseline
(:func:`~excavator_surrogate.evaluate.horizon.horizon_errors`)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .png import png_path, save_png

HOLD = "hold"
"""The label of the baseline that predicts no motion (``θ[k+n] = θ[k]``)."""


def plot_horizon(
    out: str | Path,
    result: Mapping[str, Any],
    *,
    dpi: int = 110,
) -> Path:
    """Draw ``result`` (:func:`~excavator_surrogate.evaluate.horizon.horizon_errors`) to the
    PNG ``out`` (written atomically) and return its path: RMSE [° or the joint's display unit]
    against the horizon [s], the first model (the evaluated one) thick, the others thin, hold
    dashed grey,
    and the table's horizons marked."""
    from matplotlib.figure import Figure  # no pyplot: backend-independent, thread-safe

    out = png_path(out)
    curve = result["curve"]
    t = np.asarray(curve["seconds"])
    shown_in = result["display"]  # joint -> {"unit", "factor"}
    n = len(shown_in)
    fig = Figure(figsize=(3.2 * n, 3.2), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, n, sharex=True))
    labels = [k for k in curve["rmse"] if k != HOLD]
    for ax, (joint, disp) in zip(axes, shown_in.items(), strict=True):

        def values(label: str, name: str = joint, f: float = disp["factor"]) -> np.ndarray:
            return np.array([np.nan if v is None else v * f for v in curve["rmse"][label][name]])

        for i, label in enumerate(labels):
            ax.plot(t, values(label), color=f"C{i}", lw=2.0 if i == 0 else 1.0, label=label)
        ax.plot(t, values(HOLD), color="0.5", ls="--", lw=1.0, label="hold (no motion)")
        for h in result["horizons_s"]:
            ax.axvline(h, color="0.85", lw=0.8, zorder=0)
        ax.set_title(joint)
        ax.set_xlabel("horizon [s]")
        ax.set_ylabel(f"RMSE [{disp['unit']}]")
        ax.set_ylim(bottom=0.0)
    axes[0].legend(fontsize="small")
    fig.suptitle(
        f"Prediction horizon: error after {result['n_start']} measured starts "
        f"(every {result['stride_s']:g} s), recorded commands"
    )
    return save_png(fig, out, dpi=dpi)
