"""Benchmark: training throughput of the paper's 2 x 128 LSTM against this machine's matmul peak.

For each training mode (windowed H-step rollouts; stateful teacher-forced; stateful with
free-run feedback) and sequence batch size, one measured slice of a real training epoch (the
package's own mode strategies, loss, clipping, NaN rule and Adam step: ``run_epoch``) on
synthetic 4-joint data.  Reported: loss samples/s, recurrent steps/s and achieved GFLOP/s.
Next to it, timed in the same run with the same threads: the dense float32 matmul peak of a
GEMM shaped like the LSTM's largest one (``(n_batch, 2H) @ (2H, 4H)``), and of a 1024^3 GEMM.
Also side by side: free-run training of the demo's network with the hand-written chunk
backward (``fused_backward``, :mod:`excavator_surrogate.training.free_run`) against autograd,
interleaved, at least :data:`GOAL_FUSED_RATIO` times the samples/s; the fused one-step cell
(``SurrogateNet.step``) against a one-step ``nn.LSTM`` call, as used by free-run training and
validation; and an epoch's validation of
its two candidates (raw and averaged weights) as one batched free run
(``free_run_errors``) against two separate ones (``free_run_error``), on validation splits
shaped like the real cases' (one long segment, two sessions, 24 short runs): the batched
run must take at most :data:`GOAL_VAL_RATIO` of the separate runs' time, and stepped in
NumPy (what training runs) at most :data:`GOAL_NUMPY_RATIO` of the batched torch loop's on
the long segments, and never more than it.

FLOP count (multiply-add = 2): forward per recurrent step and sample
``F = 2 * sum_layers 4H (n_in + H) + 2 * (H * H_head + H_head * n_joint)``; a step inside the
loss costs ``3F`` (forward, input and weight gradients), a burn-in step ``F``.

Usage::

    python bench/train.py                       # 2 threads, CPU, ~2 min
    python bench/train.py --threads 1 --seconds 3
    python bench/train.py --device cuda         # the same ratios on a GPU

The last line is one JSON object with a ``goals`` object of booleans.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

import numpy as np
import torch

from excavator_surrogate.devices import resolve_device
from excavator_surrogate.surrogate.model import ModelConfig, Surrogate, SurrogateNet
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training import TrainConfig
from excavator_surrogate.training.batches import make_data
from excavator_surrogate.training.loop import run_epoch
from excavator_surrogate.training.loss import default_loss
from excavator_surrogate.training.modes import make_mode
from excavator_surrogate.training.optim import Optimisation
from excavator_surrogate.training.parallel import SingleProcess
from excavator_surrogate.training.resume import start

GOAL_RATIO = 0.30
"""Stateful training of the 2 x 128 LSTM reaches this fraction of the matmul peak (issue 15)."""
GOAL_FUSED_RATIO = 1.25
"""Free-run training with the hand-written chunk backward (``fused_backward``) reaches at least
this multiple of the autograd path's samples/s on the demo's network (1.39-1.43 measured on the
reference machine)."""
GOAL_VAL_RATIO = 0.8
"""Validating two candidates in one batched free run takes at most this fraction of two
separate free runs' time (0.5-0.7 measured on the reference machine)."""
GOAL_NUMPY_RATIO = 0.7
"""On a validation split of few long episodes (:data:`LONG_VAL_SHAPES`), the batched free
run stepped in NumPy (:mod:`excavator_surrogate.surrogate.numpy_loop`, what training runs)
takes at most this fraction of the same run stepped in torch (0.38-0.56 measured on computer
E with one thread), and it is never slower: on 24 short runs (48 rows) the matrix products
dominate either way (0.81)."""
LONG_VAL_SHAPES = ("1 segment", "2 sessions")
"""The validation shapes where one free-run step is mostly dispatch, not arithmetic."""


def _parse() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    p.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N")
    p.add_argument("--seconds", type=float, default=6.0, help="timed seconds per configuration")
    p.add_argument(
        "--seq-batch", default="16,64,256", help="stateful sequence batches (comma-separated)"
    )
    p.add_argument("--hidden", type=int, default=128, help="LSTM width (paper: 128)")
    return p.parse_args()


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def matmul_gflops(n: int, k: int, m: int, *, dev: torch.device, seconds: float = 1.0) -> float:
    """Achieved GFLOP/s of ``(n, k) @ (k, m)`` in float32, best of a few timed bursts."""
    a, b = torch.randn(n, k, device=dev), torch.randn(k, m, device=dev)
    for _ in range(5):
        a @ b
    best = 0.0
    for _ in range(3):
        _sync(dev)
        t0, reps = time.perf_counter(), 0
        while time.perf_counter() - t0 < seconds / 3:
            a @ b
            reps += 1
        _sync(dev)
        best = max(best, 2.0 * n * k * m * reps / (time.perf_counter() - t0) / 1e9)
    return best


def forward_flop(mc: ModelConfig) -> float:
    """Forward FLOP per recurrent step and sample (see the module docstring)."""
    h, f = mc.hidden, 0.0
    n_in = mc.n_feature
    for _ in range(mc.n_layer):
        f += 2 * 4 * h * (n_in + h)
        n_in = h
    return f + 2 * (h * mc.head_hidden + mc.head_hidden * mc.n_joint)


def _dataset(n_joint: int = 4, n_episode: int = 12, n_step: int = 4000):
    spec = synthetic_spec(n_joint)
    eps = [
        synthetic_episode(spec, kind="sine" if i % 2 else "step", n_step=n_step, seed=i)
        for i in range(n_episode)
    ]
    return spec, eps


def measure(
    cfg: TrainConfig, spec, episodes, *, dev: torch.device, seconds: float, warm: bool = True
) -> dict[str, float]:
    """Train slices of an epoch of ``cfg`` for about ``seconds``; throughput and GFLOP/s."""
    torch.manual_seed(0)
    mcfg = cfg.model_config(cfg.n_feature(spec), spec.n_joint)
    st = start(cfg, mcfg, spec, episodes, None)
    sur = st.surrogate(cfg, dev)  # as the training loop builds it
    net = sur.net
    data = make_data(episodes, st.norm, dev)
    optim = Optimisation.build(cfg, sur)
    mode = make_mode(cfg, data, sur)
    par = SingleProcess(device=dev)
    loss_fn = default_loss(lambda_bias=cfg.lambda_bias)
    f = forward_flop(mcfg)

    def one(seconds: float) -> tuple[int, float]:
        """Train whole epochs (the last one cut at the deadline): (loss samples, seconds)."""
        _sync(dev)
        t0 = time.perf_counter()
        deadline, total, epoch = t0 + seconds, 0, 10  # epoch 10: past any teacher warm-up
        while time.perf_counter() < deadline:
            _, n = run_epoch(
                mode,
                net,
                par,
                optim.opt,
                epoch=epoch,
                rng=np.random.default_rng(epoch),
                loss_fn=loss_fn,
                grad_clip=cfg.grad_clip,
                lr_at=lambda: None,
                past=lambda: time.perf_counter() > deadline,
                show=lambda it, **kw: it,
            )
            total, epoch = total + n, epoch + 1
        _sync(dev)
        return total, time.perf_counter() - t0

    if warm:
        one(min(1.0, seconds / 4))  # warm-up
    n, dt = one(seconds)
    if cfg.mode == "windowed":  # a sample is a window end: H rollout steps re-run W steps each
        grad_steps = float(n * cfg.window * cfg.horizon)
        fwd_steps = 0.0
    else:
        per_seq = cfg.seq_len - cfg.burn_in + 1  # loss samples per sub-sequence
        grad_steps = float(n)
        fwd_steps = n / per_seq * (cfg.burn_in - 1)
    flop = 3 * f * grad_steps + f * fwd_steps
    return {
        "samples_per_s": n / dt,
        "steps_per_s": (grad_steps + fwd_steps) / dt,
        "gflops": flop / dt / 1e9,
        "seconds": dt,
    }


def step_speed(mc: ModelConfig, *, n_batch: int, dev: torch.device, seconds: float) -> dict:
    """Forward + backward of 40 one-step calls: fused cell vs a one-step ``nn.LSTM`` call."""
    net = SurrogateNet(mc).to(dev)
    x = torch.randn(n_batch, 40, mc.n_feature, device=dev)

    def module_step(x_t, state):
        y, state = net.forward_seq(x_t.unsqueeze(1), state)
        return y[:, 0], state

    out = {}
    for name, step in (("module", module_step), ("cell", net.step)):

        def go(step=step):
            state, ys = net.init_state(n_batch), []
            for k in range(x.shape[1]):
                y, state = step(x[:, k], state)
                ys.append(y)
            torch.stack(ys, 1).square().mean().backward()

        go()
        _sync(dev)
        t0, reps = time.perf_counter(), 0
        while time.perf_counter() - t0 < seconds:
            go()
            reps += 1
        _sync(dev)
        out[name] = n_batch * 40 * reps / (time.perf_counter() - t0)
    return out


def fused_speed(spec, episodes, *, dev: torch.device, seconds: float, rounds: int = 5) -> dict:
    """Free-run training samples/s of the demo's network (2 x 64 LSTM, play features, velocity
    input, residual head, end stops and speed bounds, batch 64, one thread) with the hand-written chunk
    backward (``fused_backward``) and through autograd: ``rounds`` interleaved slices each,
    medians, and their ratio."""
    joints = [
        replace(
            j,
            theta_min=None if j.periodic else -1.5,
            theta_max=None if j.periodic else 1.5,
            omega_max=1.0,
        )
        for j in spec.joints
    ]
    spec = replace(spec, joints=tuple(joints))
    episodes = [replace(e, spec=spec) for e in episodes]
    demo = TrainConfig(
        hidden=64,
        head_hidden=64,
        play=(0.02, 0.05, 0.1),
        velocity_input=True,
        residual=True,
        mode="stateful",
        feedback="free",
        teacher_epochs=0,
        seq_batch=64,
        num_threads=1,
        end_stops=True,
        tensorboard=False,
        device=str(dev),
    )
    speeds: dict[str, list[float]] = {"fused": [], "autograd": []}
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the demo trains: one member per core, one thread each
    try:
        for r in range(rounds + 1):  # the first round warms up and is not kept
            for how in speeds:
                cfg = replace(demo, fused_backward=how == "fused")
                got = measure(cfg, spec, episodes, dev=dev, seconds=seconds, warm=False)
                if r:
                    speeds[how].append(got["samples_per_s"])
    finally:
        torch.set_num_threads(threads)
    f, a = (float(np.median(speeds[k])) for k in ("fused", "autograd"))
    return {"fused_samples_per_s": f, "autograd_samples_per_s": a, "ratio": f / a}


VAL_SHAPES = {"1 segment": (1, 600), "2 sessions": (2, 600), "24 runs": (24, 300)}
"""Validation splits timed: (episodes, samples each), like the continuous case, the sessions
case and h1-dev (shorter: the time per step does not depend on the length)."""


def validation_speed(mc: ModelConfig, spec, eps, *, dev: torch.device, reps: int = 3) -> dict:
    """Seconds per free-run step of validating two candidates, batched and separately
    (medians of ``reps`` interleaved runs per validation shape), and their ratio."""
    from excavator_surrogate.surrogate.features import Normalization
    from excavator_surrogate.surrogate.rollout import rollout_episodes
    from excavator_surrogate.surrogate.stacked import stack
    from excavator_surrogate.surrogate.validation import (
        free_run_error,
        free_run_errors,
        score_runs,
    )

    norm = Normalization.fit([e.theta for e in eps], [e.u for e in eps], spec).to(dev)
    torch.manual_seed(0)
    cands = []
    for _ in range(2):  # two sets of weights of one architecture, as the raw and the average
        net = SurrogateNet(mc).to(dev).eval()
        cands.append(
            Surrogate(net=net, spec=spec, norm=norm, model_cfg=mc, mode="stateful", end_stops=True)
        )
    out = {}
    for name, (n_ep, n_step) in VAL_SHAPES.items():
        val = [
            synthetic_episode(spec, kind="step", n_step=n_step, seed=100 + i) for i in range(n_ep)
        ]
        times: dict[str, list[float]] = {"batched": [], "torch": [], "separate": []}
        for _ in range(reps + 1):  # the first round warms up and is not kept
            for how in times:
                t0 = time.perf_counter()
                if how == "batched":  # what training runs: stacked, stepped in NumPy
                    free_run_errors(cands, val)
                elif how == "torch":  # stacked, stepped by the torch closed loop
                    runs = rollout_episodes(stack(cands), val * len(cands))
                    [score_runs(runs[c * n_ep : (c + 1) * n_ep], s) for c, s in enumerate(cands)]
                else:
                    [free_run_error(c, val) for c in cands]
                times[how].append(time.perf_counter() - t0)
        steps = n_step - mc.window
        b, tb, sep = (
            float(np.median(times[k][1:])) / steps for k in ("batched", "torch", "separate")
        )
        out[name] = {
            "batched_s_per_step": b,
            "torch_batched_s_per_step": tb,
            "separate_s_per_step": sep,
            "ratio": b / sep,
            "numpy_ratio": b / tb,
        }
    return out


def main() -> int:
    args = _parse()
    dev = resolve_device(args.device)
    torch.set_num_threads(args.threads)
    spec, eps = _dataset()
    batches = sorted(int(b) for b in args.seq_batch.split(","))  # stateful sequence batches
    nb_max = batches[-1]
    h = args.hidden
    base = TrainConfig(
        hidden=h,
        head_hidden=h,
        window=30,
        num_threads=args.threads,
        tensorboard=False,
        device=str(dev),
    )
    configs: list[tuple[str, TrainConfig]] = [
        ("windowed H=1", replace(base, mode="windowed", horizon=1, batch_size=256)),
        ("windowed H=10", replace(base, mode="windowed", horizon=10, batch_size=256)),
    ]
    stateful = replace(base, mode="stateful", seq_len=150, burn_in=30, tbptt=10)
    for nb in batches:
        configs.append((f"stateful teacher b={nb}", replace(stateful, seq_batch=nb)))
        configs.append(
            (
                f"stateful free b={nb}",
                replace(stateful, seq_batch=nb, feedback="free", teacher_epochs=0),
            )
        )
    print(f"device {dev}, {torch.get_num_threads()} threads, hidden {h}", file=sys.stderr)
    results = {}
    for name, cfg in configs:
        results[name] = measure(cfg, spec, eps, dev=dev, seconds=args.seconds)
        r = results[name]
        print(
            f"{name:>24}: {r['samples_per_s']:9.0f} samples/s {r['steps_per_s']:10.0f} steps/s "
            f"{r['gflops']:7.1f} GFLOP/s",
            file=sys.stderr,
        )
    # float32 matmul setting: oneDNN may run float32 GEMMs / RNNs in bf16 (AMX) when allowed
    bf16 = {}
    if dev.type == "cpu" and hasattr(torch.backends.mkldnn, "rnn"):
        mk = torch.backends.mkldnn
        saved = (mk.matmul.fp32_precision, mk.rnn.fp32_precision)
        try:
            mk.matmul.fp32_precision = mk.rnn.fp32_precision = "bf16"
            for name, cfg in configs:
                if name.startswith("stateful") and name.endswith(f"b={nb_max}"):
                    bf16[name] = measure(cfg, spec, eps, dev=dev, seconds=args.seconds)
                    print(
                        f"{name + ' bf16':>24}: {bf16[name]['samples_per_s']:9.0f} samples/s",
                        file=sys.stderr,
                    )
        except (RuntimeError, ValueError) as e:  # no bf16 support in this build / CPU
            print(f"oneDNN bf16 not available: {e}", file=sys.stderr)
        finally:
            mk.matmul.fp32_precision, mk.rnn.fp32_precision = saved
    # the peak, timed after the training slices in the same process and thread setting
    peak_shape = matmul_gflops(nb_max, 2 * h, 4 * h, dev=dev)
    peak_big = matmul_gflops(1024, 1024, 1024, dev=dev)
    peak = max(peak_shape, peak_big)
    mc = ModelConfig(n_feature=spec.n_feature, n_joint=spec.n_joint, hidden=h, head_hidden=h)
    cell = step_speed(mc, n_batch=16, dev=dev, seconds=min(3.0, args.seconds))
    val = validation_speed(mc, spec, eps, dev=dev)
    fused = fused_speed(spec, eps, dev=dev, seconds=min(2.0, args.seconds))
    for r in results.values():
        r["fraction_of_peak"] = r["gflops"] / peak
    print(
        f"\nmatmul peak: {peak_shape:.1f} GFLOP/s ({nb_max} x {2 * h} @ {2 * h} x {4 * h}), "
        f"{peak_big:.1f} GFLOP/s (1024^3)\n"
        f"{'mode':>24} | samples/s | GFLOP/s | of peak\n"
        + "\n".join(
            f"{k:>24} | {r['samples_per_s']:9.0f} | {r['gflops']:7.1f} | {r['fraction_of_peak']:6.1%}"
            for k, r in results.items()
        )
        + "".join(
            f"\n{k + ' bf16':>24} | {r['samples_per_s']:9.0f} | "
            f"{r['samples_per_s'] / results[k]['samples_per_s']:.2f}x float32 (accuracy not verified)"
            for k, r in bf16.items()
        )
        + f"\nfree-run training, the demo's 2 x 64 network (batch 64), hand-written chunk "
        f"backward vs autograd: {fused['ratio']:.2f}x ({fused['fused_samples_per_s']:.0f} vs "
        f"{fused['autograd_samples_per_s']:.0f} samples/s)"
        + f"\none-step cell vs one-step nn.LSTM (batch 16, fwd+bwd): "
        f"{cell['cell'] / cell['module']:.2f}x ({cell['cell']:.0f} vs {cell['module']:.0f} steps/s)"
        + "".join(
            f"\nvalidation of 2 candidates, {k}: batched {1e3 * r['batched_s_per_step']:.3f} ms "
            f"per step, separate {1e3 * r['separate_s_per_step']:.3f} ms ({r['ratio']:.2f}x)"
            for k, r in val.items()
        )
    )
    best_stateful = max(r["fraction_of_peak"] for k, r in results.items() if "teacher" in k)
    best_free = max(r["fraction_of_peak"] for k, r in results.items() if "free" in k)
    small = f"stateful teacher b={batches[0]}"
    large = f"stateful teacher b={nb_max}"
    print(
        json.dumps(
            {
                "bench": "train",
                "device": str(dev),
                "threads": torch.get_num_threads(),
                "hidden": h,
                "matmul_peak_gflops": round(peak, 1),
                "matmul_shape_gflops": round(peak_shape, 1),
                "results": {k: {n: round(v, 4) for n, v in r.items()} for k, r in results.items()},
                "validation_s_per_step": {
                    k: {n: float(f"{v:.3g}") for n, v in r.items()} for k, r in val.items()
                },
                "ratios": {
                    "stateful_teacher_of_peak": round(best_stateful, 3),
                    "stateful_free_of_peak": round(best_free, 3),
                    "large_over_small_batch": round(
                        results[large]["samples_per_s"] / results[small]["samples_per_s"], 2
                    ),
                    "cell_over_module_step": round(cell["cell"] / cell["module"], 2),
                    "fused_over_autograd_free_run": round(fused["ratio"], 2),
                    **{
                        f"validation_batched_over_separate {k}": round(r["ratio"], 2)
                        for k, r in val.items()
                    },
                    **{
                        f"validation_numpy_over_torch_batched {k}": round(r["numpy_ratio"], 2)
                        for k, r in val.items()
                    },
                    **{
                        f"bf16_over_fp32 {k}": round(
                            r["samples_per_s"] / results[k]["samples_per_s"], 2
                        )
                        for k, r in bf16.items()
                    },
                },
                "goals": {
                    "stateful_ge_30pct_of_peak": best_stateful >= GOAL_RATIO,
                    "fused_cell_faster": cell["cell"] > cell["module"],
                    "fused_free_run_ge_1_25x": fused["ratio"] >= GOAL_FUSED_RATIO,
                    "batched_validation_faster": all(
                        r["ratio"] <= GOAL_VAL_RATIO for r in val.values()
                    ),
                    "numpy_validation_faster_on_segments": all(
                        val[k]["numpy_ratio"] <= GOAL_NUMPY_RATIO for k in LONG_VAL_SHAPES
                    ),
                    "numpy_validation_never_slower": all(
                        r["numpy_ratio"] <= 1.0 for r in val.values()
                    ),
                },
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
