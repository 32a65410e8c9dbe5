"""Kalman fusion figure (paper Fig. 3): raw angle, gyro-integrated angle, fused angle (+ truth).

A linear joint's figure shows its stroke the same way, in the joint's printed unit (mm ...).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..clean.filters import integrate_gyro
from ..data.episode import Episode
from ..errors import ConfigError, DataError
from ..io_utils import atomic_path


def plot_fusion_arrays(
    time: np.ndarray,
    theta_raw: np.ndarray,
    omega_raw: np.ndarray,
    theta_fused: np.ndarray,
    *,
    dt: float,
    path: str | Path,
    theta_true: np.ndarray | None = None,
    trusted: np.ndarray | None = None,
    joint_name: str = "joint",
    title: str | None = None,
    unit: str = "rad",
    factor: float = 1.0,
) -> Path:
    """Write the fusion figure for one joint as PNG.

    Args:
        time: (n_step,) sample times [s].
        theta_raw: (n_step,) measured angle theta_t [rad].
        omega_raw: (n_step,) measured gyro rate omega_t [rad/s].
        theta_fused: (n_step,) fused angle theta_hat_t [rad].
        dt: sample period [s].
        path: output PNG.
        theta_true: optional (n_step,) true angle [rad].
        trusted: optional (n_step,) bool flags c_t; untrusted raw samples are marked.
        joint_name: used in the title and axis label.
        title: figure title (default names the joint).
        unit: the unit drawn: ``rad`` (an angle), or a linear joint's ``m``, ``cm`` or ``mm``
            (the arrays are then its stroke [m] and stroke rate [m/s]).
        factor: drawn value = stored value x ``factor`` (``JointSpec.display_factor``:
            1000 for a stroke drawn in mm).

    The gyro-integrated angle is ``theta_intg_t = theta_hat_0 + dt * sum_{j=1..t} omega_j``
    (anchored at the first fused sample, then pure integration: it shows the gyro drift).

    Returns:
        ``path``.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    time = np.asarray(time, dtype=float)
    n = time.shape[0]
    arrays = {"theta_raw": theta_raw, "omega_raw": omega_raw, "theta_fused": theta_fused}
    if theta_true is not None:
        arrays["theta_true"] = theta_true
    for name, arr in arrays.items():
        if np.shape(arr) != (n,):
            raise DataError(None, f"fusion plot: {name} has shape {np.shape(arr)}, expected ({n},)")
    theta_raw, theta_fused = np.asarray(theta_raw, dtype=float), np.asarray(theta_fused, float)
    theta_intg = theta_fused[0] + integrate_gyro(np.asarray(omega_raw, dtype=float), dt)
    what, rate = ("angle", "gyro") if unit == "rad" else ("stroke", "rate")

    fig, ax = plt.subplots(figsize=(9, 4.5), layout="constrained")
    ax.plot(time, factor * theta_raw, color="tab:blue", lw=0.9, label=rf"raw {what} $\theta_t$")
    ax.plot(
        time,
        factor * theta_intg,
        color="tab:orange",
        lw=1.0,
        label=rf"integrated {rate} $\theta^{{intg}}_t$",
    )
    ax.plot(time, factor * theta_fused, color="tab:red", lw=1.3, label=r"fused $\hat\theta_t$")
    if theta_true is not None:
        ax.plot(time, factor * np.asarray(theta_true), color="k", lw=0.9, ls="--", label="truth")
    if trusted is not None:
        bad = ~np.asarray(trusted, dtype=bool)
        if bad.any():
            ax.plot(
                time[bad],
                factor * theta_raw[bad],
                "x",
                color="tab:purple",
                ms=4,
                label=r"untrusted ($c_t=0$)",
            )
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{joint_name} {what} [{unit}]")
    ax.set_title(title or f"Kalman fusion, {joint_name} joint")
    ax.grid(alpha=0.3)
    # under the axes: a long log leaves no corner free, and inside it hid the data
    fig.legend(loc="outside lower center", ncol=len(ax.get_legend_handles_labels()[1]), fontsize=8)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=130)
    plt.close(fig)
    return path


def plot_fusion(
    raw: Episode,
    cleaned: Episode,
    *,
    joint: str | int,
    path: str | Path,
    t_range: tuple[float, float] | None = None,
) -> Path:
    """Fusion figure for one joint of an episode and its cleaned version (a linear joint's
    stroke drawn in its printed unit: ``JointSpec.display_unit``, ``display_factor``).

    Args:
        raw: measured episode (its ``theta``/``omega``; ``theta_true`` drawn if present).
        cleaned: ``clean_episode(raw)`` (its ``theta`` and ``trusted``).
        joint: joint name or index.
        path: output PNG.
        t_range: optional ``(t_start, t_stop)`` [s] window to draw.

    Returns:
        ``path``.
    """
    names = raw.spec.names
    if isinstance(joint, str):
        if joint not in names:
            raise ConfigError(f"fusion plot: unknown joint '{joint}'; choose one of {list(names)}")
        k = names.index(joint)
    else:
        k = int(joint)
        if not 0 <= k < len(names):
            raise ConfigError(f"fusion plot: joint index {k} out of range 0..{len(names) - 1}")
    if cleaned.n_step != raw.n_step:
        raise DataError(
            None, f"fusion plot: raw has {raw.n_step} samples, cleaned {cleaned.n_step}"
        )
    sel = np.ones(raw.n_step, dtype=bool)
    if t_range is not None:
        sel = (raw.time >= t_range[0]) & (raw.time <= t_range[1])
        if sel.sum() < 2:
            raise ConfigError(f"fusion plot: t_range {t_range} selects fewer than 2 samples")
    theta_raw = raw.theta[:, k]
    theta_true = None if raw.theta_true is None else raw.theta_true[:, k]
    if raw.spec.joints[k].periodic:
        theta_raw = np.unwrap(theta_raw)
        if theta_true is not None:
            # the truth on the raw angle's branch: unwrapped, then shifted by whole turns
            theta_true = np.unwrap(theta_true)
            theta_true = theta_true + 2 * np.pi * np.round(
                (theta_raw[0] - theta_true[0]) / (2 * np.pi)
            )
    truth = None if theta_true is None else theta_true[sel]
    trusted = None if cleaned.trusted is None else cleaned.trusted[sel, k]
    j = raw.spec.joints[k]
    return plot_fusion_arrays(
        raw.time[sel],
        theta_raw[sel],
        raw.omega[sel, k],
        cleaned.theta[sel, k],
        dt=raw.spec.dt,
        path=path,
        theta_true=truth,
        trusted=trusted,
        joint_name=names[k],
        unit=j.display_unit,
        factor=j.display_factor,
    )
