"""Figure-2-style closed-loop comparison: upper row omega, lower row theta, one column per joint."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .png import save_png


def plot_cbe(
    path: str | Path,
    *,
    time: np.ndarray,
    omega_ref: np.ndarray,
    theta_ref: np.ndarray,
    predictions: Mapping[str, tuple[np.ndarray, np.ndarray]],
    names: Sequence[str],
    warmup: int = 0,
    title: str = "",
    ref_label: str = "reference",
    bands: Mapping[float, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = None,
    ood: np.ndarray | None = None,
    units: Sequence[tuple[str, str]] | None = None,
    scores: Mapping[str, tuple[Sequence[float | None], Sequence[float | None]]] | None = None,
) -> Path:
    """Write a PNG comparing surrogate free-runs with the reference.

    Args:
        path: output PNG (written atomically).
        time: (n_step,) [s].
        omega_ref: (n_step, n_joint) reference velocity [rad/s].
        theta_ref: (n_step, n_joint) reference angle [rad] (periodic joints unwrapped).
        predictions: model label -> ``(omega_hat, theta_hat)``, each (n_step, n_joint).
        names: joint names (column titles).
        warmup: samples shaded as warm-up (recorded data fed to the model).
        title: figure title.
        ref_label: legend label of the reference.
        bands: the first (primary) model's uncertainty bands, level -> ``(omega_lo,
            omega_hi, theta_lo, theta_hi)``, each (n_step, n_joint); shaded, widest palest.
        ood: (n_step,) bool, steps flagged out of distribution: marked as a red strip at the
            bottom of every panel.
        units: per joint ``(ω unit, θ unit)`` of the values given (e.g. ``("mm/s", "mm")``
            for a linear joint); every panel then names its own; None: rad/s and rad.
        scores: model label -> ``(omega_r2, theta_r2)``, each (n_joint,) R² of this episode
            (None: undefined), written in each panel's corner, the first model first; models
            of ``predictions`` without one are left out.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    n_joint = len(names)
    fig, axes = plt.subplots(
        2, n_joint, figsize=(3.2 * n_joint, 5.3), sharex=True, squeeze=False, layout="constrained"
    )
    styles = ["-", "--", ":", "-."]
    for j, name in enumerate(names):
        for row, (ref, unit, sym) in enumerate(
            ((omega_ref, "rad/s", "ω"), (theta_ref, "rad", "θ"))
        ):
            ax = axes[row, j]
            ax.plot(time, ref[:, j], color="k", lw=1.2, label=ref_label, zorder=3)
            for level in sorted(bands or {}, reverse=True):  # the widest band first, palest
                lo, hi = bands[level][2 * row], bands[level][2 * row + 1]  # type: ignore[index]
                ax.fill_between(
                    time,
                    lo[:, j],
                    hi[:, j],
                    color="C0",
                    alpha=0.15 if level == max(bands) else 0.3,  # type: ignore[arg-type]
                    lw=0,
                    label=f"{round(100 * level)} % band",
                    zorder=1,
                )
            for i, (label, (om, th)) in enumerate(predictions.items()):
                y = om if row == 0 else th
                # the first (primary) model on top of the baselines, under the reference
                ax.plot(
                    time,
                    y[:, j],
                    lw=1.0,
                    ls=styles[i % len(styles)],
                    label=label,
                    zorder=2.5 - i / (len(predictions) + 1),
                    alpha=1.0 if i == 0 else 0.7,
                )
            # y-range from the reference and the first (primary) model: a diverging baseline
            # must not squash the comparison
            first = next(iter(predictions.values()), None)
            vals = [ref[:, j]] + (
                [(first[0] if row == 0 else first[1])[:, j]] if first is not None else []
            )
            v = np.concatenate(vals)
            v = v[np.isfinite(v)]
            if v.size:
                lo, hi = float(v.min()), float(v.max())
                pad = 0.1 * (hi - lo) if hi > lo else 0.1 * max(abs(hi), 1e-3)
                ax.set_ylim(lo - pad, hi + pad)
            if warmup > 0:
                ax.axvspan(time[0], time[min(warmup, len(time) - 1)], color="0.9", lw=0)
            if ood is not None and ood.any():
                # flagged steps: a red strip along the bottom of the panel
                ax.fill_between(
                    time,
                    0,
                    0.04,
                    where=ood,
                    color="red",
                    lw=0,
                    transform=ax.get_xaxis_transform(),
                    label="out of distribution",
                )
            if scores:
                text = _score_text(scores, list(predictions), row, j)
                if text:
                    ax.text(
                        0.98,
                        0.97,
                        text,
                        transform=ax.transAxes,
                        ha="right",
                        va="top",
                        fontsize=7,
                        bbox={"facecolor": "white", "alpha": 0.75, "lw": 0, "pad": 1.5},
                        zorder=4,
                    )
            if row == 0:
                ax.set_title(name)
            else:
                ax.set_xlabel("time [s]")
            if units is not None:
                ax.set_ylabel(f"{sym} [{units[j][row]}]")
            elif j == 0:
                ax.set_ylabel(f"{sym} [{unit}]")
            ax.grid(alpha=0.3)
    # one legend for every panel, under them: inside the first panel it hid that joint's data
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(
        handles,
        labels,
        loc="outside lower center",
        ncol=min(len(labels), 2 * n_joint),
        fontsize=8,
        frameon=False,
    )
    if title:
        fig.suptitle(title, fontsize=10)
    path = save_png(fig, Path(path), dpi=110)  # tagged: an evaluation replaces only its own
    plt.close(fig)
    return path


def _score_text(
    scores: Mapping[str, tuple[Sequence[float | None], Sequence[float | None]]],
    labels: Sequence[str],
    row: int,
    j: int,
) -> str:
    """One panel's corner: ``R² 0.977`` for the first model, ``ARX R² 0.666`` for the others
    (``—`` where undefined), in the order of ``labels``."""
    lines = []
    for i, label in enumerate(label for label in labels if label in scores):
        r2 = scores[label][row][j]
        value = "—" if r2 is None or not np.isfinite(r2) else f"{r2:.3f}"
        lines.append(f"R² {value}" if i == 0 else f"{label} R² {value}")
    return "\n".join(lines)
