"""An independent test plant: a 3-joint hydraulic arm (boom, arm, bucket; no swing) in numpy.

Written for the import tests and the README example; it shares nothing with the
package's MuJoCo plant.  Model (per joint ``i``, integrated at ``sim_rate_hz``):

- operator command ``c_i`` in [-1, 1]: random steps smoothed by a 0.2 s lag;
- transport delay ``delay_s``, then a first-order spool lag ``tau_spool_s``;
- valve dead zone ``dead_zone`` (fraction of the stroke): ``x = sign(s) max(|s| - dz, 0) / (1 - dz)``;
- flow-limited cylinders: reference speed ``omega_ref = omega_max_i * x``, all scaled down
  together when the pump flow ``sum |omega_ref_i| * a_i`` exceeds ``q_max``;
- rigid links under gravity: ``J_i domega/dt = k_h (omega_ref - omega) - tau_gravity_i``
  (semi-implicit Euler), hard joint limits.

The log has what a real controller records: time in ms at ``log_rate_hz`` with timing
jitter, angles in degrees with sensor noise, two one-way valve duties per joint in %
(``<joint>_up_pct``, ``<joint>_down_pct``), and no velocity channel.
"""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np

JOINTS = ("boom", "arm", "bucket")
LENGTH_M = (5.7, 2.9, 1.5)
MASS_KG = (3000.0, 1500.0, 700.0)
LIMITS_DEG = ((-40.0, 60.0), (30.0, 150.0), (-30.0, 140.0))
OMEGA_MAX = (0.35, 0.5, 0.8)
"""Speed at full valve opening [rad/s]."""
AREA = (2.0, 1.2, 0.8)
"""Relative cylinder flow per rad/s."""
G = 9.81

MAPPING_TOML = """\
# exsur import mapping for the 3-joint test arm (see docs/import.md)
[machine]
name = "arm3"
rate_hz = 20.0            # target rate after resampling [Hz]

[time]
column = "t_ms"
unit = "ms"

[import]
nan = "fail"              # or "fill" (short gaps, up to max_fill samples)
min_steps = 40            # the model window: shorter episodes are dropped

[split]
by = "fraction"
fractions = [0.5, 0.25, 0.25]
seed = 0

[[joints]]
name = "boom"
limits = [-40.0, 60.0]    # in the angle's unit (deg)
angle = { column = "boom_deg", unit = "deg" }
command = { up = "boom_up_pct", down = "boom_down_pct", unit = "%", range = [-1000.0, 1000.0] }

[[joints]]
name = "arm"
limits = [30.0, 150.0]
angle = { column = "arm_deg", unit = "deg" }
command = { up = "arm_up_pct", down = "arm_down_pct", unit = "%", range = [-1000.0, 1000.0] }

[[joints]]
name = "bucket"
limits = [-30.0, 140.0]
angle = { column = "bucket_deg", unit = "deg" }
command = { up = "bucket_up_pct", down = "bucket_down_pct", unit = "%", range = [-1000.0, 1000.0] }
"""


def operator_commands(n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) smoothed random valve commands in [-1, 1]."""
    c = np.zeros((n, 3))
    for i in range(3):
        k = 0
        while k < n:
            hold = int(rng.uniform(0.5, 3.0) / dt)
            level = 0.0 if rng.random() < 0.3 else rng.uniform(-1.0, 1.0)
            c[k : k + hold, i] = level
            k += hold
    a = dt / 0.2
    out = np.empty_like(c)
    acc = np.zeros(3)
    for k in range(n):  # operator smoothing (first-order lag)
        acc += a * (c[k] - acc)
        out[k] = acc
    return np.clip(out, -1.0, 1.0)


def gravity_torque(theta: list[float]) -> list[float]:
    """Gravity torque [Nm] about each joint; ``theta`` relative joint angles [rad]."""
    phi = 0.0
    px = [0.0]
    com = []
    for th, length in zip(theta, LENGTH_M):
        phi += th
        com.append(px[-1] + 0.5 * length * math.cos(phi))
        px.append(px[-1] + length * math.cos(phi))
    return [sum(MASS_KG[k] * G * (com[k] - px[i]) for k in range(i, 3)) for i in range(3)]


def simulate(
    *,
    duration_s: float = 30.0,
    seed: int = 0,
    sim_rate_hz: float = 500.0,
    log_rate_hz: float = 100.0,
    jitter_s: float = 0.001,
    noise_deg: float = 0.03,
    delay_s: float = 0.04,
    tau_spool_s: float = 0.06,
    dead_zone: float = 0.1,
    q_max: float = 1.2,
    k_h: float = 5e7,
) -> dict[str, np.ndarray]:
    """Simulate and log the arm.

    Returns:
        Columns ``t_ms`` (n,), ``<joint>_deg`` (n,), ``<joint>_up_pct`` / ``<joint>_down_pct``
        (n,), plus the noiseless ``<joint>_true_deg`` for checks.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / sim_rate_hz
    n = int(duration_s * sim_rate_hz) + 1
    cmd = operator_commands(n, dt, rng)
    delay = round(delay_s / dt)
    inertia = [
        MASS_KG[i] * LENGTH_M[i] ** 2 / 3.0
        + sum(MASS_KG[k] * LENGTH_M[i] ** 2 for k in range(i + 1, 3))
        for i in range(3)
    ]
    lim = [(math.radians(a), math.radians(b)) for a, b in LIMITS_DEG]
    theta = [math.radians(10.0), math.radians(90.0), math.radians(50.0)]
    omega = [0.0, 0.0, 0.0]
    spool = [0.0, 0.0, 0.0]
    th_log = np.empty((n, 3))
    a_sp = dt / tau_spool_s
    for k in range(n):
        th_log[k] = theta
        c = cmd[max(k - delay, 0)]
        ref = []
        for i in range(3):
            spool[i] += a_sp * (c[i] - spool[i])
            s = spool[i]
            x = math.copysign(max(abs(s) - dead_zone, 0.0) / (1.0 - dead_zone), s)
            ref.append(OMEGA_MAX[i] * x)
        flow = sum(abs(r) * a for r, a in zip(ref, AREA))
        if flow > q_max:
            ref = [r * q_max / flow for r in ref]
        tg = gravity_torque(theta)
        for i in range(3):
            w = (omega[i] + dt / inertia[i] * (k_h * ref[i] - tg[i])) / (
                1.0 + dt * k_h / inertia[i]
            )
            th = theta[i] + dt * w
            if th < lim[i][0] or th > lim[i][1]:
                th = min(max(th, lim[i][0]), lim[i][1])
                w = 0.0
            theta[i], omega[i] = th, w
    t_sim = dt * np.arange(n)
    n_log = int(duration_s * log_rate_hz)
    t_log = np.arange(n_log) / log_rate_hz + rng.uniform(-jitter_s, jitter_s, n_log)
    t_log = np.clip(t_log, 0.0, t_sim[-1])
    t_log[0] = 0.0
    out: dict[str, np.ndarray] = {"t_ms": np.round(t_log * 1e3, 3)}
    for i, name in enumerate(JOINTS):
        true = np.degrees(np.interp(t_log, t_sim, th_log[:, i]))
        out[f"{name}_deg"] = true + rng.normal(0.0, noise_deg, n_log)
        out[f"{name}_true_deg"] = true
        held = cmd[np.clip(np.searchsorted(t_sim, t_log, side="right") - 1, 0, n - 1), i]
        out[f"{name}_up_pct"] = np.round(np.maximum(held, 0.0) * 100.0, 2)
        out[f"{name}_down_pct"] = np.round(np.maximum(-held, 0.0) * 100.0, 2)
    return out


LOG_COLUMNS = ("t_ms", *(f"{j}_{s}" for j in JOINTS for s in ("deg", "up_pct", "down_pct")))


def write_csv(
    path: str | Path, cols: dict[str, np.ndarray], *, columns: tuple[str, ...] = LOG_COLUMNS
) -> Path:
    """Write ``columns`` of ``cols`` as CSV (gzip if the name ends in .gz)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = np.column_stack([np.asarray(cols[c], dtype=np.float64) for c in columns])
    lines = [",".join(columns)] + [
        ",".join(f"{v:.6g}" if c != "t_ms" else f"{v:.3f}" for c, v in zip(columns, row))
        for row in data
    ]
    text = "\n".join(lines) + "\n"
    if path.name.endswith(".gz"):
        with gzip.open(path, "wt") as f:
            f.write(text)
    else:
        path.write_text(text)
    return path


def write_logs(
    folder: str | Path, *, n_logs: int = 4, duration_s: float = 30.0, seed: int = 0
) -> list[Path]:
    """Write ``n_logs`` CSV logs ``run01.csv`` ... into ``folder``; returns their paths."""
    return [
        write_csv(
            Path(folder) / f"run{i + 1:02d}.csv", simulate(duration_s=duration_s, seed=seed + i)
        )
        for i in range(n_logs)
    ]
