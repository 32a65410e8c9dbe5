"""``exsur clean``: consistency-aware adaptive Kalman filtering of a dataset (paper Sec. IV)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from ..outdir import out_dir, preset_files
from .common import add_out
from .knobs import add_set_option, configs

if TYPE_CHECKING:
    from ..clean.config import CleanConfig


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``clean`` subcommand."""
    from ..clean.config import METHODS

    p = subparsers.add_parser(
        "clean",
        help="fuse angles and gyro rates into kinematically consistent data",
        description=(
            "Clean every episode of DATASET with the consistency-aware adaptive Kalman filter "
            "and write a new dataset with the same splits (theta = fused angle, omega = its "
            "backward difference, trusted_<joint> = consistency flags)."
        ),
    )
    p.add_argument("dataset", metavar="DATASET", help="input dataset folder (with manifest.json)")
    add_out(p, "output dataset folder", replaced=True)
    p.add_argument(
        "--method",
        choices=METHODS,
        default=None,
        help="paper = Algorithm 1 (its open parts read as in docs/cleaning.md); gyro = gyro input + bias; gyro3 = gyro measurement + bias; "
        "rts = gyro + RTS smoother (default: preset, else rts)",
    )
    p.add_argument(
        "--preset",
        default=None,
        metavar="NAME",
        help="preset name or .toml path (its [clean] table)",
    )
    p.add_argument(
        "--plot",
        action="store_true",
        help="also write the fusion figure (paper Fig. 3) of the first episode, each joint, to DIR/figures",
    )
    add_set_option(p, ("clean",))
    p.set_defaults(func=run)


def _config(args: argparse.Namespace) -> CleanConfig:
    """CleanConfig from the preset's ``[clean]`` table (if any), ``--set``, then ``--method``."""
    return configs(args, ("clean",), {"clean": {"method": args.method}})["clean"]


def run(args: argparse.Namespace) -> int:
    """Handler of ``exsur clean``; returns the exit code."""
    from ..clean.api import clean_dataset
    from ..data.dataset import read_manifest

    cfg = _config(args)
    inputs = [args.dataset, *preset_files(args.preset)]
    with out_dir(args.out, overwrite=args.overwrite, inputs=inputs, kind="dataset"):
        out = clean_dataset(args.dataset, args.out, config=cfg)
    manifest = read_manifest(out)
    summary = manifest.get("cleaning", {})
    print(f"cleaned dataset: {out}  (method {cfg.method})")
    from ..spec import MachineSpec

    joints = {j.name: j for j in MachineSpec.from_dict(manifest["spec"]).joints}
    for joint, m in summary.items():
        js = joints.get(joint)  # a linear joint prints in its own unit (mm ...)
        f, unit = (js.display_factor, js.display_unit) if js is not None else (1.0, "rad")
        line = (
            f"  {joint:>10s}: untrusted {100 * m['untrusted_frac']:5.2f} %, "
            f"rms(fused - raw) {f * m['rms_fused_minus_raw']:.4f} {unit}"
        )
        if m.get("rmse_raw") is not None:
            line += f", rmse raw {f * m['rmse_raw']:.4f} -> fused {f * m['rmse_fused']:.4f} {unit}"
        if m.get("jump_recall") is not None:
            prec = m.get("jump_precision")
            line += f", jumps P {prec if prec is None else round(prec, 3)} R {m['jump_recall']:.3f}"
        print(line)
    if args.plot:
        _plot_first(Path(args.dataset), out)
    return 0


def _plot_first(src: Path, out: Path) -> None:
    from ..data.dataset import read_manifest
    from ..data.episode import read_episode, read_metadata
    from ..plotting.fusion import plot_fusion

    cleaned = read_episode(out / read_manifest(out)["episodes"][0]["file"])
    for entry in read_manifest(src)["episodes"]:
        if read_metadata(src / entry["file"]).get("name") == cleaned.name:
            raw = read_episode(src / entry["file"])
            break
    else:  # pragma: no cover - write_dataset keeps names
        return
    for name in raw.spec.names:
        path = plot_fusion(
            raw, cleaned, joint=name, path=out / "figures" / f"fusion_{raw.name}_{name}.png"
        )
        print(f"  figure: {path}")
