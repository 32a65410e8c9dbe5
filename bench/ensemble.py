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
on training.  Ends with ONE JSON line.  Usage::

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--members", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=1.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    k = args.members
    members = [member(s) for s in range(k)]
    theta0 = np.tile([0.0, 0.0, 1.5, 0.5], (1, 1))
    result: dict[str, float] = {}
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
        result.update(
            {
                f"single_n{n_envs}": round(r_single),
                f"merged_{k}_n{n_envs}": round(r_merged),
                f"separate_{k}_n{n_envs}": round(r_sep),
                f"merged_over_single_n{n_envs}": round(r_merged / r_single, 3),
                f"merged_over_separate_n{n_envs}": round(r_merged / r_sep, 3),
            }
        )
        print(
            f"n_envs {n_envs:5d}: single {r_single:10.0f}/s  merged x{k} {r_merged:10.0f}/s  "
            f"separate x{k} {r_sep:10.0f}/s  merged/single {r_merged / r_single:.2f}  "
            f"merged/separate {r_merged / r_sep:.2f}"
        )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
