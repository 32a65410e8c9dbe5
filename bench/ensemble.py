"""Cost of a merged seed ensemble in the env engine, side by side with its alternatives.

Steps per second of :class:`SurrogateEngine` (stateful, the vector env's kernel) at
``n_envs`` in {1, 1024} for

- ``single``: one paper-size member (2 x 128 LSTM, head 128);
- ``merged_K``: K members merged by :func:`~excavator_surrogate.surrogate.ensemble.merge`
  into one block-diagonal 2 x (K * 128) LSTM (what ``exsur train --members K`` writes);
- ``separate_K``: the other way to run an ensemble -- K engines stepped one after another,
  omega averaged and the angle integrated once (same trajectory as ``merged_K``).

Printed ratios: ``merged_K / single`` (the price of the ensemble) and
``merged_K / separate_K`` (what merging saves).  Models are untrained: speed does not depend
on training.  Before timing, both ensembles run the same 50 steps from the same angles and
must agree (the merged block network is the members' mean, not an approximation of it).
Ends with ONE JSON line, with a ``goals`` object of booleans: the two agree; one env steps
the merged ensemble faster than the members one by one (what merging is for: a planner or
a single simulated machine); at 1024 envs merging costs at most half the separate rate (its
zero blocks are real multiply-adds: a floor against regressions, not a win).  Usage::

    python bench/ensemble.py [--members 2] [--seconds 1]
"""

from __future__ import annotations

import argparse
import functools
import json
import time

import numpy as np
import torch

from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.ensemble import merge
from excavator_surrogate.surrogate.features import Normalization
from excavator_surrogate.surrogate.model import ModelConfig, Surrogate, build_net


def member(seed: int, hidden: int = 128) -> Surrogate:
    """An untrained stateful 2 x ``hidden`` LSTM surrogate (head ``hidden``) of the default
    excavator: paper-size by default."""
    torch.manual_seed(seed)
    spec = EXCAVATOR
    cfg = ModelConfig(
        n_feature=spec.n_feature,
        n_joint=spec.n_joint,
        window=30,
        hidden=hidden,
        head_hidden=hidden,
    )
    norm = Normalization.from_arrays(
        x_mean=np.zeros(spec.n_feature),
        x_std=np.ones(spec.n_feature),
        y_mean=np.zeros(spec.n_joint),
        y_std=np.full(spec.n_joint, 0.05),
        spec=spec,
    )
    return Surrogate(
        net=build_net(cfg).eval(), spec=spec, norm=norm, model_cfg=cfg, mode="stateful"
    )


def step_separately(parts: list[SurrogateEngine], u: np.ndarray) -> None:
    """One ensemble step with K engines: each steps from the same angle, omega is averaged and
    the angle integrated once (no end stops on the benchmark machine's free run)."""
    theta = parts[0].theta.clone()
    omega = torch.stack([p.step(u)[1] for p in parts]).mean(0)
    theta += omega * parts[0].dt
    for p in parts:
        p.theta.copy_(theta)


def rate(step, n_envs: int, seconds: float) -> float:
    """Env-steps per second of ``step(u)`` over about ``seconds``."""
    rng = np.random.default_rng(0)
    u = rng.uniform(-1000, 1000, (n_envs, 4))
    for _ in range(5):
        step(u)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        step(u)
        n += 1
    return n * n_envs / (time.perf_counter() - t0)


GOAL_MERGED_OVER_SEPARATE_N1 = 1.0
"""One env: the merged ensemble against its members stepped one after another."""
GOAL_MERGED_OVER_SEPARATE_N1024 = 0.5
"""1024 envs: the floor of the same ratio (block-diagonal weights are dense work)."""
AGREE_RAD = 1e-5
"""Largest angle difference [rad] between the two ensembles after 50 steps."""


def agreement(members: list[Surrogate], n_envs: int = 8, n_step: int = 50) -> float:
    """Largest |theta_merged - theta_separate| [rad] over ``n_step`` steps of random commands
    from the same angles (``n_envs`` envs)."""
    rng = np.random.default_rng(1)
    th0 = np.tile([0.0, 0.0, 1.5, 0.5], (n_envs, 1))
    merged = SurrogateEngine(merge(members), n_envs=n_envs)
    parts = [SurrogateEngine(m, n_envs=n_envs) for m in members]
    for e in (merged, *parts):
        e.reset(th0)
    worst = 0.0
    for _ in range(n_step):
        u = rng.uniform(-1000, 1000, (n_envs, 4))
        merged.step(u)
        step_separately(parts, u)
        worst = max(worst, float((merged.theta - parts[0].theta).abs().max()))
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--members", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=1.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    k = args.members
    members = [member(s) for s in range(k)]
    theta0 = np.tile([0.0, 0.0, 1.5, 0.5], (1, 1))
    diff = agreement(members)
    print(f"merged vs separate over 50 steps: largest angle difference {diff:.2e} rad")
    result: dict[str, float | dict[str, bool]] = {"max_theta_diff_rad": diff}
    over_separate: dict[int, float] = {}  # merged / separate rate per n_envs, as recorded
    for n_envs in (1, 1024):
        th0 = np.repeat(theta0, n_envs, axis=0)
        single = SurrogateEngine(members[0], n_envs=n_envs)
        merged = SurrogateEngine(merge(members), n_envs=n_envs)
        parts = [SurrogateEngine(m, n_envs=n_envs) for m in members]
        for e in (single, merged, *parts):
            e.reset(th0)
        r_single = rate(single.step, n_envs, args.seconds)
        r_merged = rate(merged.step, n_envs, args.seconds)
        r_sep = rate(functools.partial(step_separately, parts), n_envs, args.seconds)
        over_separate[n_envs] = round(r_merged / r_sep, 3)
        result.update(
            {
                f"single_n{n_envs}": round(r_single),
                f"merged_{k}_n{n_envs}": round(r_merged),
                f"separate_{k}_n{n_envs}": round(r_sep),
                f"merged_over_single_n{n_envs}": round(r_merged / r_single, 3),
                f"merged_over_separate_n{n_envs}": over_separate[n_envs],
            }
        )
        print(
            f"n_envs {n_envs:5d}: single {r_single:10.0f}/s  merged x{k} {r_merged:10.0f}/s  "
            f"separate x{k} {r_sep:10.0f}/s  merged/single {r_merged / r_single:.2f}  "
            f"merged/separate {r_merged / r_sep:.2f}"
        )
    result["goals"] = {
        "merged_equals_separate": diff <= AGREE_RAD,
        "merged_faster_than_separate_n1": over_separate[1] >= GOAL_MERGED_OVER_SEPARATE_N1,
        f"merged_ge_{GOAL_MERGED_OVER_SEPARATE_N1024:g}x_separate_n1024": (
            over_separate[1024] >= GOAL_MERGED_OVER_SEPARATE_N1024
        ),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
