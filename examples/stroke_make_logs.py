"""Write stroke-sensing excavator logs and their import mapping: a machine with linear joints.

Many machines sense cylinder strokes (stroke-sensing cylinders, string potentiometers), not
joint angles.  This turns a simulated dataset of the hydraulic stand-in (``exsur simulate
--preset quick-hydraulic``, or any preset) into such a machine's logs: the swing stays an
encoder angle in degrees, and boom, arm and bucket become cylinder strokes in mm through a
made-up but plausible linkage (:data:`LINKAGES`; a 75 t class machine's cylinders run
about 1.7-2.2 m of stroke).  Each episode becomes one CSV (time in s, the swing in deg, the
strokes in mm, the commands as they were), named by its split, and ``stroke_excavator.toml``
maps them with ``position = { unit = "mm" }``, the stroke limits in mm and the linkage, so
that ``exsur import`` -> ``exsur train`` -> ``exsur evaluate`` print mm.

    python examples/stroke_make_logs.py --out stroke_demo --preset quick-hydraulic
    exsur import stroke_demo/logs --mapping stroke_demo/stroke_excavator.toml \
        --out stroke_demo/dataset
    exsur train stroke_demo/dataset --out stroke_demo/model
    exsur evaluate stroke_demo/model/best.pt stroke_demo/dataset --out stroke_demo/eval

:func:`make_logs` is the Python entry point (a benchmark calls it with its own preset).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

from excavator_surrogate.data import load_dataset
from excavator_surrogate.simulate import SimulateConfig, simulate_dataset
from excavator_surrogate.spec import EXCAVATOR, Linkage

LINKAGES: dict[str, Linkage] = {
    # a, b: the joint axis to the cylinder's two pivots [m]; phi: the angle between the
    # joint angle and the triangle's angle at the joint [rad]; l0: the retracted pin-to-pin
    # length [m].  Chosen so that theta + phi stays inside (0, pi) over the joint's limits
    # (the stroke is monotonic in the angle) with about 0.1 m of stroke left at either end.
    "boom": Linkage(a=1.25, b=3.4, phi=1.15, l0=2.05),  # [-0.75, 0.85] rad -> 0.25-2.03 m
    "arm": Linkage(a=0.9, b=3.2, phi=-0.25, l0=2.25),  # [0.55, 2.65] rad -> 0.11-1.66 m
    "bucket": Linkage(a=0.75, b=2.6, phi=0.62, l0=1.75),  # [-0.60, 2.50] rad -> 0.10-1.60 m
}
"""The made-up linkage of each stroke-sensed joint (the swing keeps its encoder)."""

MAPPING_NAME = "stroke_excavator.toml"
"""The mapping file :func:`make_logs` writes next to ``logs/``."""


def stroke_limits(name: str) -> tuple[float, float]:
    """The stroke range [m] that joint ``name``'s angle limits give through its linkage."""
    j = EXCAVATOR.joints[EXCAVATOR.names.index(name)]
    s = LINKAGES[name].stroke(np.array([j.theta_min, j.theta_max]))
    return float(s.min()), float(s.max())


def mapping_toml(rate_hz: float) -> str:
    """The import mapping of the logs: swing in deg, boom/arm/bucket strokes in mm."""
    out = [
        "# A stroke-sensing excavator (examples/stroke_make_logs.py): the swing is an encoder",
        "# angle in deg, boom, arm and bucket are cylinder strokes in mm (linear joints).",
        "[machine]",
        'name = "stroke-excavator"',
        f"rate_hz = {rate_hz:g}",
        "",
        "[time]",
        'column = "time_s"',
        'unit = "s"',
        "",
        "[split]",
        'by = "glob"',
        'train = ["train_*"]',
        'val = ["val_*"]',
        'test = ["test_*"]',
        "",
        "[[joints]]",
        'name = "swing"',
        "periodic = true",
        'angle = { column = "swing_deg", unit = "deg" }',
        'command = { column = "u_swing", unit = "physical", range = [-1000, 1000] }',
    ]
    for name, link in LINKAGES.items():
        lo, hi = stroke_limits(name)
        out += [
            "",
            "[[joints]]",
            f'name = "{name}"',
            f'position = {{ column = "{name}_stroke_mm", unit = "mm" }}',
            f"limits = [{math.floor(1e4 * lo) / 10:.1f}, {math.ceil(1e4 * hi) / 10:.1f}]",
            f"linkage = {{ a = {1e3 * link.a:g}, b = {1e3 * link.b:g}, "
            f"l0 = {1e3 * link.l0:g}, phi = {math.degrees(link.phi):.4g} }}",
            f'command = {{ column = "u_{name}", unit = "physical", range = [-1000, 1000] }}',
        ]
    return "\n".join(out) + "\n"


def write_episode_csv(path: Path, time: np.ndarray, theta: np.ndarray, u: np.ndarray) -> Path:
    """One log: ``time_s``, ``swing_deg``, ``<joint>_stroke_mm``, ``u_<joint>`` columns."""
    names = EXCAVATOR.names
    cols: dict[str, np.ndarray] = {"time_s": time, "swing_deg": np.degrees(theta[:, 0])}
    for k, name in enumerate(names):
        if name in LINKAGES:
            cols[f"{name}_stroke_mm"] = 1e3 * LINKAGES[name].stroke(theta[:, k])
    for k, name in enumerate(names):
        cols[f"u_{name}"] = u[:, k]
    head = ",".join(cols)
    body = np.column_stack(list(cols.values()))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, body, delimiter=",", header=head, comments="", fmt="%.6f")
    return path


def make_logs(
    out_dir: str | Path,
    *,
    seed: int = 0,
    preset: str = "quick-hydraulic",
    dataset: str | Path | None = None,
    **overrides: object,
) -> Path:
    """Write ``out_dir/logs/<split>_<k>.csv`` and ``out_dir/stroke_excavator.toml``.

    Args:
        out_dir: the folder to write (created; the logs of an earlier call are replaced).
        seed: the simulation seed.
        preset: the preset whose ``[simulate]`` table makes the data (``tiny`` for tests).
        dataset: an already simulated dataset of the 4-joint excavator to convert instead.
        **overrides: ``[simulate]`` fields that replace the preset's (``n_train=4``).

    Returns:
        The mapping's path.
    """
    out_dir = Path(out_dir)
    with tempfile.TemporaryDirectory() as tmp:
        if dataset is None:
            cfg = SimulateConfig.from_preset(preset, seed=seed, **overrides)
            dataset = simulate_dataset(cfg, out=Path(tmp) / "sim")
        ds = load_dataset(dataset)
        if ds.spec.names != EXCAVATOR.names:
            raise SystemExit(f"{dataset}: needs the swing/boom/arm/bucket excavator's data")
        for old in (out_dir / "logs").glob("*_[0-9][0-9][0-9].csv"):  # a previous call's logs
            old.unlink()
        for split in ("train", "val", "test"):
            for k, ep in enumerate(ds.split(split)):
                write_episode_csv(
                    out_dir / "logs" / f"{split}_{k:03d}.csv", ep.time, ep.theta, ep.u
                )
        mapping = out_dir / MAPPING_NAME
        mapping.write_text(mapping_toml(ds.spec.rate_hz))
    return mapping


def main(argv: list[str] | None = None) -> int:
    """Write OUT/logs/*.csv and OUT/stroke_excavator.toml."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("stroke_demo"), help="folder to write")
    ap.add_argument("--preset", default="quick-hydraulic", help="simulation preset")
    ap.add_argument("--dataset", type=Path, help="convert this simulated dataset instead")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    mapping = make_logs(args.out, seed=args.seed, preset=args.preset, dataset=args.dataset)
    logs = args.out / "logs"
    print(f"wrote {len(list(logs.glob('*.csv')))} logs in {logs} and {mapping}")
    print(f"next: exsur import {logs} --mapping {mapping} --out {args.out / 'dataset'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
