"""``exsur export CKPT --out model.onnx``: ONNX single-step model with explicit (h, c)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..surrogate.model import Surrogate


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``export`` subcommand."""
    p = sub.add_parser(
        "export",
        help="export a surrogate checkpoint to ONNX (single step, state as inputs/outputs)",
        description="Export the single-step surrogate to ONNX: inputs theta, u, h, c; outputs "
        "omega, theta_next, h_out, c_out (feature normalisation folded into the weights). "
        "Windowed checkpoints export their W-sample window model unless --mode stateful. "
        "The export is verified against torch with onnxruntime. See docs/env.md.",
    )
    p.add_argument("ckpt", type=Path, help="checkpoint .pt written by 'exsur train'")
    p.add_argument("--out", type=Path, required=True, help="target .onnx file")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace --out even if exsur did not write it (docs/design.md)",
    )
    p.add_argument(
        "--mode",
        choices=["stateful", "windowed"],
        default=None,
        help="graph to export (default: the checkpoint's training mode)",
    )
    p.add_argument("--opset", type=int, default=18, help="ONNX opset (default 18)")
    p.add_argument(
        "--exporter",
        choices=["auto", "dynamo", "torchscript"],
        default="auto",
        help="torch exporter: dynamo (torch.export), torchscript (legacy, fast) or auto "
        "(dynamo, falling back to torchscript; torchscript for opsets 11 to 17)",
    )
    p.add_argument(
        "--uncertainty",
        action="store_true",
        help="add the output omega_members (M, batch, joints): each ensemble member's omega "
        "from the same call, whose spread is the uncertainty (a merged seed ensemble, "
        "stateful graph) and, with a training coverage record, the output ood (batch, joints): "
        "the per-joint out-of-distribution flag; the band calibration and coverage record go "
        "into the metadata",
    )
    p.add_argument("--no-verify", action="store_true", help="skip the onnxruntime check")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Export, then step torch and onnxruntime side by side for 50 steps and print the error.

    The comparison runs on the temporary file before it is renamed onto ``--out``
    (:func:`~excavator_surrogate.env.export.export_onnx`'s ``verify``), so an export that
    fails anywhere leaves nothing there (and an existing file untouched)."""
    from ..env.export import export_onnx
    from ..env.surrogate_env import load_surrogate
    from ..outdir import check_out_file

    check_out_file(args.out, inputs=[args.ckpt], example="model.onnx", overwrite=args.overwrite)
    sur = load_surrogate(args.ckpt)
    mode = args.mode or sur.mode
    checked: list[str] = []

    def verify(path: Path) -> None:
        checked.append(_compare(path, sur, mode, uncertainty=args.uncertainty))

    out = export_onnx(
        sur,
        args.out,
        mode=mode,
        opset=args.opset,
        exporter=args.exporter,
        uncertainty=args.uncertainty,
        verify=None if args.no_verify else verify,
    )
    msg = f"{out}: exported {sur.name} ({mode}, {sur.spec.n_joint} joints, W={sur.window})"
    print(msg + "".join(checked))
    return 0


def _compare(path: Path, sur: Surrogate, mode: str, *, uncertainty: bool) -> str:
    """Step torch and onnxruntime (the graph at ``path``) side by side for 50 steps from 4
    random poses; returns the report, ``"; max |torch - onnxruntime| ..."``."""
    import numpy as np

    from ..env.engine import SurrogateEngine
    from ..env.onnx_stepper import OnnxStepper
    from ..env.tasks import sample_pose

    rng = np.random.default_rng(0)
    theta0 = np.stack([sample_pose(sur.spec, rng) for _ in range(4)])
    lo = np.array([c.u_min for c in sur.spec.u_specs])
    hi = np.array([c.u_max for c in sur.spec.u_specs])
    stepper = OnnxStepper(path)
    engine = SurrogateEngine(sur, n_envs=4, mode=mode, uncertainty=uncertainty)
    stepper.reset(theta0)
    engine.reset(theta0)
    err, n_flag, n_differ = 0.0, 0, 0
    for _ in range(50):
        u = rng.uniform(lo, hi, (4, sur.spec.n_u))
        th, om = stepper.step(u)
        th_t, om_t = engine.step(u)
        err = max(err, float(np.abs(om - om_t.cpu().numpy()).max()))
        err = max(err, float(np.abs(th - th_t.cpu().numpy()).max()))
        if uncertainty and engine.unc is not None:
            om_m = engine.unc.omega_members.cpu().numpy()
            err = max(err, float(np.abs(stepper.omega_members - om_m).max()))
        if stepper.ood is not None and engine.unc is not None:
            ood_t = engine.unc.ood.cpu().numpy()
            n_flag += int(ood_t.sum())
            n_differ += int((stepper.ood != ood_t).sum())
    msg = f"; max |torch - onnxruntime| over 50 steps = {err:.2e}"
    if stepper.ood is not None:
        msg += f"; OOD flags: {n_flag} raised by torch, {n_differ} differ in onnxruntime"
    return msg
