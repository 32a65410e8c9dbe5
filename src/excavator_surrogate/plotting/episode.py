"""Episode figure: one column per joint, rows command u, position theta, velocity omega."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data import Episode
from ..spec import JointSpec
from .png import png_path, save_png


def row_labels(j: JointSpec) -> tuple[str, str, str]:
    """The y labels of joint ``j``'s rows: its command in ``u_unit``, then θ and ω in the
    joint's printed units (``theta [rad]``, ``omega [rad/s]``; a stroke ``stroke [mm]``,
    ``velocity [mm/s]``)."""
    if j.linear:
        return f"u [{j.u_unit}]", f"stroke [{j.display_unit}]", f"velocity [{j.rate_unit}]"
    return f"u [{j.u_unit}]", "theta [rad]", "omega [rad/s]"


def plot_episode(ep: Episode, *, out: str | Path, title: str | None = None, dpi: int = 110) -> Path:
    """Draw ``ep`` to the PNG ``out`` (written atomically) and return its path.

    Rows: ``u`` [the joint's command unit], ``theta`` [rad], ``omega`` [rad/s] against time
    [s]; one column per joint of ``ep.spec``.  A linear joint's stroke and velocity are drawn
    in its printed unit (the stored m times ``JointSpec.display_factor``: mm, mm/s ...).
    Every column is labelled when the columns' units differ (a stroke among angles, commands
    in other units); otherwise the first.  Ground-truth columns, when present and different
    from the measurement, are overlaid as thin dashed lines.
    """
    from matplotlib.figure import Figure  # no pyplot: backend-independent, thread-safe

    out = png_path(out)
    n = ep.spec.n_joint
    fig = Figure(figsize=(3.2 * n + 1.0, 7.0), layout="constrained")
    axes = fig.subplots(3, n, sharex=True, squeeze=False)
    t = ep.time
    labels = [row_labels(j) for j in ep.spec.joints]  # per joint: (u, theta, omega)
    every = ep.spec.any_linear or len(set(labels)) > 1
    rows = ((ep.u, None), (ep.theta, ep.theta_true), (ep.omega, ep.omega_true))
    for r, (arr, truth) in enumerate(rows):
        for k, name in enumerate(ep.spec.names):
            f = 1.0 if r == 0 else ep.spec.joints[k].display_factor  # θ, ω: printed unit
            ax = axes[r, k]
            ax.plot(t, f * arr[:, k], lw=0.8, color=f"C{r}")
            if truth is not None and not np.array_equal(truth[:, k], arr[:, k]):
                ax.plot(t, f * truth[:, k], lw=0.6, ls="--", color="k", label="true")
                ax.legend(loc="upper right", fontsize=7)
            ax.grid(True, lw=0.3, alpha=0.5)
            if r == 0:
                ax.set_title(name)
            if every or k == 0:
                ax.set_ylabel(labels[k][r])
            if r == 2:
                ax.set_xlabel("time [s]")
    fig.suptitle(
        title
        or f"{ep.name}  ({ep.source}, {ep.condition}, {ep.n_step} samples @ {ep.spec.rate_hz:g} Hz)"
    )
    return save_png(fig, out, dpi=dpi)
