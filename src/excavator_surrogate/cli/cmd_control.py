"""``exsur control CKPT --out DIR``: MPPI and RL through the surrogate, checked on the plant."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path
from typing import Any

from .common import add_overwrite


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``control`` subcommand."""
    p = sub.add_parser(
        "control",
        help="controllers built on the surrogate, run on the plant: MPPI tracking and PPO",
        description="Track a digging-like joint-space reference on ExcavatorMujoco-v0 with MPPI "
        "planning through the surrogate, the same MPPI through the plant model itself (oracle) "
        "and a PI baseline; train PPO (Stable-Baselines3) on the surrogate and on the plant for "
        "the same env-step budget and evaluate both on the plant. Writes report.md, "
        "tracking.png, learning_curve.png, trajectories.npz, metrics.json and config.toml (every "
        "option) to --out.",
    )
    p.add_argument("ckpt", type=Path, help="surrogate checkpoint .pt")
    p.add_argument("--out", type=Path, required=True, help="report folder (replaced atomically)")
    add_overwrite(p, replaced=True)
    p.add_argument(
        "--plant",
        choices=["ideal", "hydraulic"],
        default=None,
        help="MuJoCo plant (default: the one the checkpoint was trained on, hydraulic if it "
        "does not record it; another is refused)",
    )
    p.add_argument("--samples", type=int, default=256, metavar="K", help="MPPI candidates (256)")
    p.add_argument(
        "--horizon", type=int, default=20, metavar="N", help="MPPI horizon [samples] (20)"
    )
    p.add_argument(
        "--replan",
        type=int,
        default=2,
        metavar="M",
        help="machine samples per MPPI control step (2)",
    )
    p.add_argument(
        "--bias-gain",
        type=float,
        default=0.1,
        metavar="A",
        help="velocity-bias correction of the surrogate's predictions (0: off; default 0.1)",
    )
    p.add_argument(
        "--risk",
        type=float,
        default=0.0,
        metavar="R",
        help="weight of the surrogate's uncertainty in the MPPI cost: the ensemble members' "
        "spread and out-of-distribution steps (needs a merged seed ensemble; 0: off, default)",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=1.0,
        metavar="S",
        help="stretch the digging reference (1.0: the 27-s cycle; > 0, refused where the "
        "runs would not fit in memory)",
    )
    p.add_argument(
        "--cpus",
        type=int,
        default=None,
        metavar="N",
        help="CPUs of each MPPI planner: surrogate candidates split over N processes, the "
        "oracle's mujoco.rollout on N threads (default: all usable, at most 4 and at most "
        "--samples)",
    )
    p.add_argument(
        "--mppi-seeds",
        type=int,
        default=1,
        metavar="N",
        help="repeat both MPPI runs with N noise seeds (a seed study; the tracking target then "
        "takes the worst; each oracle run adds about a minute; default 1)",
    )
    p.add_argument("--no-oracle", action="store_true", help="skip MPPI through the plant model")
    p.add_argument("--no-rl", action="store_true", help="skip the PPO comparison")
    p.add_argument(
        "--rl-steps",
        type=int,
        default=1_000_000,
        metavar="N",
        help="env-steps per PPO run (1000000)",
    )
    p.add_argument(
        "--rl-envs", type=int, default=128, metavar="N", help="parallel envs per PPO run"
    )
    p.add_argument(
        "--rl-eval", type=int, default=16, metavar="N", help="evaluation episodes on the plant (16)"
    )
    p.add_argument(
        "--rl-episode-steps", type=int, default=300, metavar="N", help="reach episode length (300)"
    )
    p.add_argument(
        "--rl-start-radius",
        type=float,
        default=1.0,
        metavar="RAD",
        help="reach starts with the swing within ± this of its target [rad] (1.0); "
        "a negative value: anywhere on the circle",
    )
    p.add_argument("--seed", type=int, default=0, help="MPPI noise and PPO seed")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run both comparisons and print the report."""
    import torch

    from ..control.mppi import MPPIConfig
    from ..control.report import run_control
    from ..control.rl import RLConfig
    from ..devices import usable_cpus
    from ..env.plants import checkpoint_plant
    from ..errors import ConfigError
    from ..io_utils import log
    from ..outdir import check_out_dir, replace_allowed
    from ..surrogate.checkpoint import load_checkpoint
    from ..surrogate.ensemble import member_head

    out_dir = check_out_dir(
        args.out, overwrite=args.overwrite, inputs=[args.ckpt], lock=True, kind="control"
    )
    torch.set_num_threads(1)
    if args.samples < 2:  # MPPI weighs at least two candidates
        raise ConfigError(f"--samples must be >= 2 (MPPI candidates), got {args.samples}")
    # the default never exceeds --samples (it was refused on 4 CPUs with --samples 3)
    cpus = min(usable_cpus(), 4, args.samples) if args.cpus is None else args.cpus
    if not 1 <= cpus <= args.samples:
        raise ConfigError(f"--cpus must be in [1, --samples = {args.samples}], got {cpus}")
    _check_flags(args)
    if not args.risk >= 0:
        raise ConfigError(f"--risk must be >= 0, got {args.risk}")
    if args.seed >= 2**32:  # PPO seeds torch, which takes no seed past 2**64; keep 32 bits
        raise ConfigError(f"--seed {args.seed}: must be < 2**32 (a 32-bit seed)")
    if args.mppi_seeds < 1:
        raise ConfigError(f"--mppi-seeds must be >= 1, got {args.mppi_seeds}")
    sur = load_checkpoint(args.ckpt)
    _check_mppi_memory(args, sur)
    _check_reference_memory(args, sur)
    if args.risk > 0 and member_head(sur) is None:
        raise ConfigError(
            f"--risk {args.risk:g} needs the spread of a merged seed ensemble; {args.ckpt} is "
            "a single network (train with members >= 2, or use --risk 0)"
        )
    # the machine check, before any run: another machine or plant is refused in one line
    plant = checkpoint_plant(sur.spec, args.plant, ckpt=args.ckpt, default="hydraulic")
    mppi = MPPIConfig(
        n_sample=args.samples,
        n_horizon=args.horizon,
        replan=args.replan,
        seed=args.seed,
        risk=args.risk,
    )
    rl = RLConfig(
        total_steps=args.rl_steps,
        n_envs=args.rl_envs,
        n_eval=args.rl_eval,
        episode_steps=args.rl_episode_steps,
        start_radius=None if args.rl_start_radius < 0 else args.rl_start_radius,
        seed=args.seed,
    )
    with replace_allowed(out_dir) if args.overwrite else contextlib.nullcontext():
        run_control(
            sur,
            args.out,
            ckpt=str(args.ckpt),
            plant=plant,
            mppi=mppi,
            rl=rl,
            do_rl=not args.no_rl,
            oracle=not args.no_oracle,
            time_scale=args.time_scale,
            bias_gain=args.bias_gain,
            cpus=cpus,
            n_seeds=args.mppi_seeds,
            log=log,
        )
    print((args.out / "report.md").read_text(encoding="utf-8"), end="")
    return 0


def _check_mppi_memory(args: argparse.Namespace, sur: Any) -> None:
    """Refuse --samples x --horizon whose MPPI rollouts cannot fit in memory (one line, before
    any run: 10^9 candidates used to end in the kernel's OOM killer)."""
    from ..surrogate.sizes import check_fits

    cfg = sur.model_cfg
    per_step = sur.spec.n_u + 4 * sur.spec.n_joint + 2 * cfg.n_layer * cfg.hidden + cfg.n_feature
    n_bytes = 8 * 4 * max(args.samples, 1) * max(args.horizon, 1) * per_step  # float64, ~4 copies
    check_fits(
        n_bytes,
        what=f"--samples {args.samples} x --horizon {args.horizon} MPPI rollouts",
        fix="lower --samples or --horizon",
    )


def _check_flags(args: argparse.Namespace) -> None:
    """Refuse the MPPI, reference and PPO flags out of range in one line naming the flag (the
    configs' own checks name their fields, e.g. ``rl: need ... n_steps``)."""
    from ..control.rl import RLConfig
    from ..errors import ConfigError

    if args.horizon < 1:
        raise ConfigError(f"--horizon must be >= 1 (MPPI samples), got {args.horizon}")
    if not 1 <= args.replan <= args.horizon:
        raise ConfigError(
            f"--replan must be in [1, --horizon = {args.horizon}] (samples applied per plan), "
            f"got {args.replan}"
        )
    if not 0 <= args.bias_gain <= 1:
        raise ConfigError(f"--bias-gain must be in [0, 1] (0: off), got {args.bias_gain:g}")
    if not args.time_scale > 0:
        raise ConfigError(f"--time-scale must be > 0 (1: the 27-s cycle), got {args.time_scale:g}")
    if args.rl_envs < 1:
        raise ConfigError(f"--rl-envs must be >= 1, got {args.rl_envs}")
    n_steps = RLConfig.n_steps  # PPO's rollout per env and update: not a flag
    if args.rl_steps < args.rl_envs * n_steps:
        raise ConfigError(
            f"--rl-steps must be >= --rl-envs x {n_steps} = {args.rl_envs * n_steps} (one PPO "
            f"update), got {args.rl_steps}"
        )


def _check_reference_memory(args: argparse.Namespace, sur: Any) -> None:
    """Refuse a --time-scale whose reference and tracking runs cannot fit in memory (one
    line, before any run: 1e9 ended in numpy's 298-GiB _ArrayMemoryError traceback, 1e6 in
    the kernel's OOM killer at 21.7 GB)."""
    from ..control.reference import REFERENCE_BYTES_PER_SAMPLE, reference_samples
    from ..surrogate.sizes import check_fits

    n_step = reference_samples(sur.spec, time_scale=args.time_scale)
    n_run = 3 + 2 * (args.mppi_seeds - 1)  # MPPI surrogate and oracle, PI; 2 per extra seed
    # per sample: the reference, the running run's angles and commands as lists of small
    # arrays (~400 B), 64 B of angles and commands kept per run
    n_bytes = n_step * (REFERENCE_BYTES_PER_SAMPLE + 400 + 64 * n_run)
    check_fits(
        n_bytes,
        what=f"--time-scale {args.time_scale:g}: a {n_step}-sample digging reference, tracked "
        f"{n_run} times,",
        fix="lower --time-scale (1: the 27-s cycle)",
    )
