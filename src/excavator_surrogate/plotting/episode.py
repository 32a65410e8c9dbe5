"""Episode figure: one column per joint, rows command u, angle theta, angular velocity omega."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data import Episode
from .png import png_path, save_png


def plot_episode(ep: Episode, *, out: str | Path, title: str | None = None, dpi: int = 110) -> Path:
    """Draw ``ep`` to the PNG ``out`` (written atomically) and return its path.

    Rows: ``u`` [command units], ``theta`` [rad], ``omega`` [rad/s] against time [s]; one
    column per joint of ``ep.spec``.  Ground-truth columns, when present and different from
    the measurement, are overlaid as thin dashed lines.
    """
    from matplotlib.figure import Figure  # no pyplot: backend-independent, thread-safe

    out = png_path(out)
    n = ep.spec.n_joint
    fig = Figure(figsize=(3.2 * n + 1.0, 7.0), layout="constrained")
    axes = fig.subplots(3, n, sharex=True, squeeze=False)
    t = ep.time
    rows = (
        ("u", ep.u, None, "command"),
        ("theta", ep.theta, ep.theta_true, "rad"),
        ("omega", ep.omega, ep.omega_true, "rad/s"),
    )
    for r, (label, arr, truth, unit) in enumerate(rows):
        for k, name in enumerate(ep.spec.names):
            ax = axes[r, k]
            ax.plot(t, arr[:, k], lw=0.8, color=f"C{r}")
            if truth is not None and not np.array_equal(truth[:, k], arr[:, k]):
                ax.plot(t, truth[:, k], lw=0.6, ls="--", color="k", label="true")
                ax.legend(loc="upper right", fontsize=7)
            ax.grid(True, lw=0.3, alpha=0.5)
            if r == 0:
                ax.set_title(name)
            if k == 0:
                ax.set_ylabel(f"{label} [{unit}]")
            if r == 2:
                ax.set_xlabel("time [s]")
    fig.suptitle(
        title
        or f"{ep.name}  ({ep.source}, {ep.condition}, {ep.n_step} samples @ {ep.spec.rate_hz:g} Hz)"
    )
    return save_png(fig, out, dpi=dpi)
