"""Training: H-step rollout loss, free-run validation, best-checkpoint selection, resume.

Two training modes produce the same :class:`~.model.SurrogateNet`:

- ``windowed`` (paper III-B): a sample is a window of ``W`` recorded samples ending at ``t``;
  the net (zero initial state) predicts ``omega[t+1]``, which is integrated into the angle,
  re-encoded with the recorded command ``u[t+1]`` and appended to the window, ``H`` times.
  Cost per epoch ~ ``n_sample * W * H`` recurrent steps.
- ``stateful`` (faster): random sub-sequences of ``seq_len`` samples; the first ``burn_in``
  samples are fed with recorded angles without gradient to build up ``(h, c)``; the rest is
  either teacher-forced (recorded angles, one fused recurrent call) or free-run (integrated
  angles fed back), with truncated BPTT: every ``tbptt`` steps the loss is back-propagated, the
  optimiser steps and state/angle are detached.  Cost per epoch ~ ``n_sample`` recurrent steps,
  and the model is then rolled out sample by sample with carried ``(h, c)``.

Loss (both modes, in normalised target units): ``SmoothL1(y_hat, y)`` averaged over the
horizon, joints and batch, plus ``lambda_bias * || mean_h y_hat - mean_h y ||^2`` (summed over
joints, averaged over the batch).  In stateful mode the "horizon" of the bias term is each TBPTT
chunk.

Model selection: after every epoch the model is rolled out in closed loop on the validation
episodes; ``val_error`` = mean over joints of RMSE(theta) / std(theta_ref) after the warm-up.
The best epoch is kept in ``best.pt``; ``last.pt`` holds the latest state for ``resume``.
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch
import torch.nn.functional as F

from ..config import dumps_toml, from_dict, to_dict
from ..data.dataset import Dataset
from ..data.episode import Episode
from ..errors import CheckpointError, ConfigError, DataError
from ..io_utils import log, progress, write_text
from .checkpoint import read_checkpoint, save_checkpoint, surrogate_from_dict
from .envelope import fill_envelope
from .features import Normalization, integrate, omega_target, unwrap_periodic
from .model import ModelConfig, Surrogate, SurrogateNet
from .rollout import rollout_episodes, window_rollout

if TYPE_CHECKING:
    from ..scale.ddp import DistContext

EpochCallback = Callable[[int, dict[str, Any]], bool]
"""``on_epoch(epoch, row) -> stop``: called after every epoch (rank 0) with the ``log.csv`` row."""


@dataclass(frozen=True)
class TrainConfig:
    """Surrogate training options (``[train]`` table of a preset)."""

    window: int = 30
    """Window length W [samples]; also the warm-up of every closed-loop rollout."""
    hidden: int = 128
    """Recurrent state width."""
    layers: int = 2
    """Stacked recurrent layers."""
    head_hidden: int = 128
    """Width of the FC layer of the output head."""
    cell: Literal["lstm", "gru"] = "lstm"
    """Recurrent cell (``gru`` is the same-size baseline)."""
    mode: Literal["windowed", "stateful"] = "windowed"
    """Training (and rollout) mode: sliding windows (paper) or carried state (faster)."""
    horizon: int = 1
    """H: rollout steps in the windowed loss (1 = one-step training)."""
    lambda_bias: float = 0.0
    """Weight of the mean-bias penalty over the horizon (paper: 0.3 for compound data)."""
    lr: float = 1e-3
    """Adam learning rate."""
    batch_size: int = 256
    """Windows per batch (windowed mode); per process with DDP (global batch = batch_size x world size)."""
    epochs: int = 50
    """Maximum number of epochs."""
    patience: int = 25
    """Early stopping: epochs without a better validation free-run error."""
    min_delta: float = 0.0
    """Relative improvement of the validation error that counts as better."""
    plateau_factor: float = 0.5
    """ReduceLROnPlateau factor on the validation error."""
    plateau_patience: int = 10
    """ReduceLROnPlateau patience [epochs] (the free-run error is noisy: keep this generous)."""
    min_lr: float = 1e-5
    """Lower bound of the learning rate."""
    lr_schedule: Literal["plateau", "cosine"] = "plateau"
    """``plateau``: ReduceLROnPlateau on the validation error (paper); ``cosine``: decay from ``lr``
    to ``min_lr`` over the run (progress = max(epoch / epochs, elapsed / max_train_seconds))."""
    grad_clip: float = 1.0
    """Clip the gradient norm to this value (0 disables)."""
    seed: int = 0
    """Seed of weight init and sampling (epoch e samples with seed (seed, e))."""
    seq_len: int = 150
    """Stateful: sub-sequence length [samples] including the burn-in."""
    burn_in: int = 30
    """Stateful: leading samples fed with recorded data, without loss or gradient."""
    tbptt: int = 10
    """Stateful: steps per truncated-BPTT chunk (one optimiser step per chunk)."""
    seq_batch: int = 16
    """Stateful: sub-sequences per batch (per process with DDP)."""
    feedback: Literal["free", "teacher"] = "teacher"
    """Stateful: after the burn-in, feed recorded angles (teacher, fast) or integrated ones (free)."""
    teacher_epochs: int = 1
    """Stateful free mode: the first epochs are teacher-forced (curriculum)."""
    epoch_samples: int = 0
    """Cap on target samples per epoch (0 = every training sample once)."""
    val_steps: int = 0
    """Truncate validation episodes to this many samples for the free-run (0 = full length)."""
    max_train_seconds: float = 0.0
    """Wall-time budget for training incl. validation [s] (0 = unlimited)."""
    device: str = "cpu"
    """Torch device: ``cpu``, ``cuda``, ``cuda:N`` or ``auto`` (CUDA if available, else CPU)."""
    num_threads: int = 1
    """Torch intra-op threads (0 keeps torch's default; 1 is fastest for these small nets on shared CPUs)."""
    ema_decay: float = 0.0
    """Keep an exponential moving average of the weights (decay per optimiser step, e.g. 0.999);
    each epoch both the raw and the averaged weights are validated and the better one competes
    for ``best.pt`` (0 = off)."""
    play: tuple[float, ...] = ()
    """Half-widths of play (backlash) operators on the scaled commands whose states are extra
    input features (valve hysteresis memory; ours, not the paper's); empty = paper's 9-D input."""
    members: int = 1
    """Seed ensemble: train this many members independently (seeds ``seed``, ``seed + 1``, ...),
    each selected by its own validation free run, and merge them into one network whose omega is
    the members' mean (``OUT/member_<i>/``; ours, not the paper's).  1 = a single network."""
    member_workers: int = 0
    """Members trained in parallel processes, each with ``num_threads`` threads (0 = one
    process per member, up to the CPU count; 1 = one after the other in this process)."""
    end_stops: bool = True
    """Keep free runs inside the machine's envelope: clip angles to the joint limits (end stops)
    and velocities to the speed bounds, in training rollouts and in every rollout of the trained
    model (stored in the checkpoint's spec)."""
    limit_margin: float = 0.02
    """End stops the spec lacks come from the angle range seen in training, widened by this
    fraction of the range on each side (negative: none from data)."""
    speed_margin: float = 0.25
    """Speed bounds the spec lacks are the largest |omega| seen in training times
    ``1 + speed_margin`` (negative: none from data)."""
    tensorboard: bool = True
    """Write TensorBoard scalars to ``OUT/tb`` (skipped if tensorboard is not installed)."""

    def __post_init__(self) -> None:
        checks = [
            (self.window >= 1, "window must be >= 1"),
            (
                self.hidden >= 1 and self.layers >= 1 and self.head_hidden >= 1,
                "hidden/layers/head_hidden must be >= 1",
            ),
            (self.horizon >= 1, "horizon must be >= 1"),
            (all(0 < b <= 1 for b in self.play), "play widths must be in (0, 1]"),
            (self.lambda_bias >= 0, "lambda_bias must be >= 0"),
            (self.lr > 0, "lr must be > 0"),
            (self.batch_size >= 1 and self.seq_batch >= 1, "batch sizes must be >= 1"),
            (self.epochs >= 1, "epochs must be >= 1"),
            (self.burn_in >= 1, "burn_in must be >= 1"),
            (self.seq_len > self.burn_in, "seq_len must exceed burn_in"),
            (self.tbptt >= 1, "tbptt must be >= 1"),
            (self.members >= 1, "members must be >= 1"),
            (math.isfinite(self.limit_margin), "limit_margin must be finite"),
            (math.isfinite(self.speed_margin), "speed_margin must be finite"),
            (self.member_workers >= 0, "member_workers must be >= 0"),
            (0 < self.plateau_factor < 1, "plateau_factor must be in (0, 1)"),
            (self.cell in ("lstm", "gru"), "cell must be lstm or gru"),
            (self.mode in ("windowed", "stateful"), "mode must be windowed or stateful"),
            (self.lr_schedule in ("plateau", "cosine"), "lr_schedule must be plateau or cosine"),
            (self.feedback in ("free", "teacher"), "feedback must be free or teacher"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ConfigError(f"[train] {msg}")

    @classmethod
    def from_preset(cls, preset: dict[str, Any], **overrides: Any) -> TrainConfig:
        """Build from a loaded preset's ``[train]`` table, then apply non-None overrides."""
        cfg = from_dict(cls, preset.get("train", {}), where="[train]")
        over = {k: v for k, v in overrides.items() if v is not None}
        return replace(cfg, **over) if over else cfg

    def model_config(self, n_feature: int, n_joint: int) -> ModelConfig:
        """Architecture implied by this config."""
        return ModelConfig(
            n_feature=n_feature,
            n_joint=n_joint,
            window=self.window,
            hidden=self.hidden,
            n_layer=self.layers,
            cell=self.cell,
            head_hidden=self.head_hidden,
        )


# ---------------------------------------------------------------------------------------------
# loss


def horizon_loss(y_hat: torch.Tensor, y: torch.Tensor, *, lambda_bias: float = 0.0) -> torch.Tensor:
    """Paper III-B loss on normalised velocities.

    Args:
        y_hat: (n_batch, H, n_joint) predictions.
        y: (n_batch, H, n_joint) targets.
        lambda_bias: weight of ``|| mean_h y_hat - mean_h y ||^2`` (summed over joints, mean over batch).

    Returns:
        Scalar ``mean SmoothL1(y_hat, y) + lambda_bias * L_bias``.
    """
    loss = F.smooth_l1_loss(y_hat, y, beta=1.0)
    if lambda_bias > 0:
        bias = (y_hat.mean(dim=1) - y.mean(dim=1)).pow(2).sum(dim=-1).mean()
        loss = loss + lambda_bias * bias
    return loss


# ---------------------------------------------------------------------------------------------
# data


@dataclass
class _Data:
    """Training episodes concatenated on the device (global sample index)."""

    x: torch.Tensor  # (T, n_feature) normalised recorded features
    theta: torch.Tensor  # (T, n_joint) recorded angles [rad]
    u: torch.Tensor  # (T, n_joint) commands
    z: torch.Tensor  # (T, P, n_joint) play states after u (P = 0: no play features)
    y: torch.Tensor  # (T, n_joint) normalised targets (row 0 of each episode NaN)
    starts: np.ndarray  # (n_episode,) global start
    lengths: np.ndarray  # (n_episode,)


def _make_data(episodes: list[Episode], norm: Normalization, device: torch.device) -> _Data:
    spec = episodes[0].spec
    xs, ths, us, zs, ys = [], [], [], [], []
    y_mean, y_std = norm.y_mean.double().numpy(), norm.y_std.double().numpy()
    for ep in episodes:
        z = norm.play_from_rest_np(ep.u, spec)
        xs.append(norm.encode_np(ep.theta, ep.u, spec, z))
        ths.append(ep.theta)
        us.append(ep.u)
        zs.append(np.zeros((ep.n_step, 0, spec.n_joint)) if z is None else z)
        ys.append((omega_target(ep.theta, spec) - y_mean) / y_std)
    lengths = np.array([ep.n_step for ep in episodes])
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])

    def t(parts: list[np.ndarray]) -> torch.Tensor:
        return torch.as_tensor(np.concatenate(parts), dtype=torch.float32, device=device)

    return _Data(x=t(xs), theta=t(ths), u=t(us), z=t(zs), y=t(ys), starts=starts, lengths=lengths)


def _windowed_indices(data: _Data, window: int, horizon: int) -> np.ndarray:
    """Global indices t of window ends with targets t+1..t+H inside the episode."""
    idx = [
        s + np.arange(window - 1, n - horizon)
        for s, n in zip(data.starts, data.lengths)
        if n - horizon > window - 1
    ]
    return np.concatenate(idx) if idx else np.zeros(0, dtype=np.int64)


def _sequence_starts(
    data: _Data, seq_len: int, burn_in: int, rng: np.random.Generator
) -> np.ndarray:
    """Global starts s of sub-sequences (steps s..s+L-1, targets up to s+L) tiling each episode."""
    stride = seq_len - burn_in + 1
    out = []
    for s0, n in zip(data.starts, data.lengths):
        last = n - 1 - seq_len  # local start must satisfy s + L <= n - 1
        if last < 0:
            continue
        off = int(rng.integers(0, min(stride, last + 1)))
        out.append(s0 + np.arange(off, last + 1, stride))
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


# ---------------------------------------------------------------------------------------------
# validation


def free_run_error(
    sur: Surrogate, episodes: list[Episode], *, max_steps: int | None = None
) -> dict[str, Any]:
    """Closed-loop validation: roll out ``episodes`` and score the angle after the warm-up.

    Returns:
        ``{"val_error": mean_j RMSE_j / std_j(theta_ref), "theta_rmse": [...], "theta_r2": [...],
        "omega_rmse": [...]}`` (per joint lists); ``val_error`` is ``inf`` if the rollout diverged.
    """
    sur.net.eval()
    runs = rollout_episodes(sur, episodes, max_steps=max_steps)
    spec = sur.spec
    th_err, th_ref, om_err = [], [], []
    for r in runs:
        w = r.warmup
        ref = unwrap_periodic(r.theta_ref, spec)[w:]
        th_err.append(r.theta_hat[w:] - ref)
        th_ref.append(ref)
        om_err.append(r.omega_hat[w:] - r.omega_ref[w:])
    e = np.concatenate(th_err)
    ref = np.concatenate(th_ref)
    eo = np.concatenate(om_err)
    rmse = np.sqrt(np.mean(e**2, axis=0))
    std = np.maximum(ref.std(axis=0), 1e-6)
    r2 = 1.0 - np.sum(e**2, axis=0) / np.maximum(np.sum((ref - ref.mean(0)) ** 2, axis=0), 1e-12)
    val = float(np.mean(rmse / std))
    if not math.isfinite(val):
        val = math.inf
    return {
        "val_error": val,
        "theta_rmse": [float(v) for v in rmse],
        "theta_r2": [float(v) for v in r2],
        "omega_rmse": [float(v) for v in np.sqrt(np.mean(eo**2, axis=0))],
    }


# ---------------------------------------------------------------------------------------------
# epochs


def _finite(x: float) -> float:
    """``x``, or +inf if it is NaN (a diverged candidate never wins)."""
    return x if math.isfinite(x) else math.inf


def _clip_step(
    net: torch.nn.Module,
    opt: torch.optim.Optimizer,
    grad_clip: float,
    lr_at: Callable[[], float | None],
) -> None:
    lr = lr_at()
    if lr is not None:
        for g in opt.param_groups:
            g["lr"] = lr
    if grad_clip > 0:
        torch.nn.utils.clip_grad_norm_(net.parameters(), grad_clip)
    opt.step()
    opt.zero_grad(set_to_none=True)


def _epoch_windowed(
    sur: Surrogate,
    data: _Data,
    opt: torch.optim.Optimizer,
    cfg: TrainConfig,
    rng: np.random.Generator,
    deadline: float,
    show: Callable[..., Any],
    lr_at: Callable[[], float | None],
    *,
    dist: _Par | None = None,
) -> tuple[float, int]:
    net, norm = sur.net, sur.norm
    limits = sur.limits()
    world = 1
    if dist is not None:  # DDP: global batch of batch_size * world, strided shard per rank
        net, world = dist.net, dist.ctx.world_size
    idx = _windowed_indices(data, cfg.window, cfg.horizon)
    rng.shuffle(idx)
    if cfg.epoch_samples > 0:
        idx = idx[: cfg.epoch_samples]
    dev = data.x.device
    ar_w = torch.arange(-cfg.window + 1, 1, device=dev)
    ar_u = torch.arange(1, cfg.horizon, device=dev)
    ar_y = torch.arange(1, cfg.horizon + 1, device=dev)
    gbs = cfg.batch_size * world
    n_batch = math.ceil(len(idx) / gbs)
    total, count = 0.0, 0
    for b in show(range(n_batch), total=n_batch, desc="train"):
        sel = idx[b * gbs : (b + 1) * gbs]
        if dist is not None:
            sel, weight, n_real = dist.ctx.shard_batch(sel)
        t = torch.as_tensor(sel, device=dev)
        x_win = data.x[t[:, None] + ar_w]
        y = data.y[t[:, None] + ar_y]
        y_hat, _ = window_rollout(
            net,
            norm,
            x_win,
            data.theta[t],
            data.u[t[:, None] + ar_u],
            z_next=data.z[t[:, None] + ar_u],
            n_horizon=cfg.horizon,
            dt=sur.spec.dt,
            limits=limits,
        )
        loss = horizon_loss(y_hat, y, lambda_bias=cfg.lambda_bias)
        if dist is not None:
            if dist.step(loss, weight, opt, cfg, lr_at) and n_real:
                total += float(loss.detach()) * n_real
                count += n_real
            if dist.past(deadline):
                break
            continue
        if torch.isfinite(loss):
            loss.backward()
            _clip_step(net, opt, cfg.grad_clip, lr_at)
            total += float(loss.detach()) * len(t)
            count += len(t)
        else:
            opt.zero_grad(set_to_none=True)
        if time.monotonic() > deadline:
            break
    return (total / count if count else math.nan), count


def _epoch_stateful(
    sur: Surrogate,
    data: _Data,
    opt: torch.optim.Optimizer,
    cfg: TrainConfig,
    rng: np.random.Generator,
    deadline: float,
    show: Callable[..., Any],
    lr_at: Callable[[], float | None],
    *,
    teacher: bool,
    dist: _Par | None = None,
) -> tuple[float, int]:
    net, norm, dt = sur.net, sur.norm, sur.spec.dt
    limits = sur.limits()
    world = 1
    if dist is not None:  # DDP: global batch of seq_batch * world sub-sequences, strided shard
        net, world = dist.net, dist.ctx.world_size
    starts = _sequence_starts(data, cfg.seq_len, cfg.burn_in, rng)
    rng.shuffle(starts)
    per_seq = cfg.seq_len - cfg.burn_in + 1
    if cfg.epoch_samples > 0:
        starts = starts[: max(1, cfg.epoch_samples // per_seq)]
    dev = data.x.device
    ar = torch.arange(cfg.seq_len, device=dev)
    gbs = cfg.seq_batch * world
    n_batch = math.ceil(len(starts) / gbs)
    total, count = 0.0, 0
    b0 = cfg.burn_in - 1  # first step whose output is in the loss
    for b in show(range(n_batch), total=n_batch, desc="train"):
        sel = starts[b * gbs : (b + 1) * gbs]
        if dist is not None:
            sel, weight, n_real = dist.ctx.shard_batch(sel)
        s = torch.as_tensor(sel, device=dev)
        g = s[:, None] + ar
        x_seq, th_seq, u_seq, y_seq = data.x[g], data.theta[g], data.u[g], data.y[g + 1]
        z_seq = data.z[g]
        state = net.init_state(len(s))
        if b0 > 0:
            with torch.no_grad():
                _, state = net.forward_seq(x_seq[:, :b0], state)
        theta = th_seq[:, b0]
        for j0 in range(b0, cfg.seq_len, cfg.tbptt):
            j1 = min(j0 + cfg.tbptt, cfg.seq_len)
            if teacher:
                y_hat, state = net.forward_seq(x_seq[:, j0:j1], state)
            else:
                ys = []
                for j in range(j0, j1):
                    y, state = net.step(norm.encode(theta, u_seq[:, j], z_seq[:, j]), state)
                    theta, _ = integrate(theta, norm.omega(y), dt=dt, limits=limits)
                    ys.append(y)
                y_hat = torch.stack(ys, dim=1)
            loss = horizon_loss(y_hat, y_seq[:, j0:j1], lambda_bias=cfg.lambda_bias)
            if dist is not None:
                if dist.step(loss, weight, opt, cfg, lr_at) and n_real:
                    total += float(loss.detach()) * n_real * y_hat.shape[1]
                    count += n_real * y_hat.shape[1]
            elif torch.isfinite(loss):
                loss.backward()
                _clip_step(net, opt, cfg.grad_clip, lr_at)
                total += float(loss.detach()) * y_hat.shape[0] * y_hat.shape[1]
                count += y_hat.shape[0] * y_hat.shape[1]
            else:
                opt.zero_grad(set_to_none=True)
            state = (state[0].detach(), state[1].detach())
            theta = theta.detach()
        if dist is not None:
            if dist.past(deadline):
                break
        elif time.monotonic() > deadline:
            break
    return (total / count if count else math.nan), count


# ---------------------------------------------------------------------------------------------
# driver


def _lr_fn(
    cfg: TrainConfig, epoch: int, t_start: float, budget: float
) -> Callable[[], float | None]:
    """Per-step learning rate of the cosine schedule (None: leave it to ReduceLROnPlateau)."""
    if cfg.lr_schedule != "cosine":
        return lambda: None

    def lr() -> float:
        progress = epoch / cfg.epochs
        if math.isfinite(budget):
            progress = max(progress, (time.monotonic() - t_start) / budget)
        progress = min(progress, 1.0)
        return cfg.min_lr + 0.5 * (cfg.lr - cfg.min_lr) * (1.0 + math.cos(math.pi * progress))

    return lr


@dataclass
class _Par:
    """Data-parallel state of one rank: the DDP view of the net and the process context."""

    ctx: DistContext
    net: Any  # scale.ddp.DDPNet
    timed: bool
    """A finite wall-time budget: stop flags (and the cosine lr) come from rank 0 every step."""

    def step(
        self,
        loss: torch.Tensor,
        weight: float,
        opt: torch.optim.Optimizer,
        cfg: TrainConfig,
        lr_at: Callable[[], float | None],
    ) -> bool:
        return self.ctx.backward_step(
            loss, weight=weight, net=self.net, opt=opt, grad_clip=cfg.grad_clip, lr_at=lr_at
        )

    def rank0_lr(self, lr_at: Callable[[], float | None]) -> Callable[[], float | None]:
        """``lr_at`` evaluated on rank 0 and broadcast (one collective per optimiser step)."""
        return lambda: self.ctx.broadcast_float(lr_at())

    def past(self, deadline: float) -> bool:
        """The deadline decision of rank 0 (no communication without a budget)."""
        if not self.timed:
            return False
        return bool(self.ctx.broadcast_float(float(time.monotonic() > deadline)))


_LOG_FIELDS = (
    "epoch",
    "time_s",
    "epoch_s",
    "val_s",
    "lr",
    "train_loss",
    "n_sample",
    "val_error",
    "val_theta_r2_min",
    "best",
    "val_error_raw",
    "val_error_ema",
    "weights",
)


def _write_log(
    path: Path, history: list[dict[str, Any]], fields: list[str] | tuple[str, ...] = _LOG_FIELDS
) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    w.writeheader()
    for row in history:
        w.writerow(row)
    write_text(path, buf.getvalue())


def _tb_writer(out: Path, enabled: bool) -> Any:
    if not enabled:
        return None
    try:
        from torch.utils.tensorboard import SummaryWriter
    except Exception:  # tensorboard not installed
        log("tensorboard is not installed; skipping TensorBoard logs (pip install tensorboard)")
        return None
    return SummaryWriter(log_dir=str(out / "tb"))


def _usable(episodes: list[Episode], n_min: int, split: str) -> list[Episode]:
    keep = [e for e in episodes if e.n_step >= n_min]
    if len(keep) < len(episodes):
        log(
            f"{split}: skipping {len(episodes) - len(keep)} episode(s) shorter than {n_min} samples"
        )
    return keep


def _episodes(cfg: TrainConfig, dataset: Dataset) -> tuple[list[Episode], list[Episode]]:
    """The training and validation episodes long enough for ``cfg`` (validation falls back to
    the training episodes, with a warning).

    Raises:
        DataError: no training episode is long enough.
    """
    n_min = cfg.window + cfg.horizon + 1 if cfg.mode == "windowed" else cfg.seq_len + 1
    train_eps = _usable(dataset.train, n_min, "train")
    if cfg.mode == "stateful" and not train_eps and dataset.train:
        longest = max(e.n_step for e in dataset.train)
        raise DataError(
            dataset.root,
            f"every training episode is shorter than seq_len + 1 = {n_min} (longest {longest})",
            fix="lower [train] seq_len",
        )
    if not train_eps:
        raise DataError(
            dataset.root,
            f"no training episode with at least {n_min} samples",
            fix="add training episodes or lower window/horizon",
        )
    val_eps = _usable(dataset.val, cfg.window + 2, "val")
    if not val_eps:
        log(
            "no usable validation episodes: validating on the training episodes (model selection is optimistic)"
        )
        val_eps = train_eps
    return train_eps, val_eps


def train(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    resume: str | Path | None = None,
    show_progress: bool | None = None,
    on_epoch: EpochCallback | None = None,
    dist: DistContext | None = None,
) -> Path:
    """Train a surrogate on ``dataset.train``, select it by free-run error on ``dataset.val``.

    Writes into ``out``: ``best.pt`` (best validation free-run), ``last.pt`` (latest, for
    resuming), ``log.csv`` (one row per epoch), ``config.toml`` and ``tb/`` (TensorBoard).

    Args:
        cfg: training options.
        dataset: episodes with ``train`` and ``val`` splits (``val`` empty: validate on train, with a warning).
        out: output folder (created).
        resume: checkpoint (``last.pt`` or ``best.pt``) to continue from; architecture must match.
        show_progress: progress bar (None: only on a terminal or with ``EXSUR_PROGRESS=1``).
        on_epoch: called after every epoch (once the checkpoints are written) with the epoch and
            its ``log.csv`` row (``val_error``, ``train_loss``, ...); returning True stops training
            (sweeps prune trials this way).  With DDP it runs on rank 0 only.
        dist: data-parallel context from :func:`excavator_surrogate.scale.ddp.init_distributed`
            (every rank calls ``train`` with the same arguments); None trains in this process.

    Returns:
        Path of ``best.pt``.

    Raises:
        DataError: no usable training episodes.  CheckpointError: bad ``resume`` file.
    """
    from ..scale.devices import resolve_device

    if cfg.members > 1:
        for given, what in (
            (resume, "resume"),
            (dist, "data-parallel training"),
            (on_epoch, "on_epoch"),
        ):
            if given is not None:
                raise ConfigError(
                    f"[train] members = {cfg.members}: {what} works per member; train each member "
                    "as a single network (members = 1) and merge them with 'exsur merge'"
                )
        return train_ensemble(cfg, dataset, out=out, show_progress=show_progress)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    main = dist is None or dist.is_main
    say = log if main else (lambda msg: None)
    try:
        device = dist.device if dist is not None else resolve_device(cfg.device)
    except ConfigError as e:
        raise ConfigError(f"[train] {e}") from e
    if cfg.num_threads > 0:
        torch.set_num_threads(cfg.num_threads)
    spec = dataset.spec
    train_eps, val_eps = _episodes(cfg, dataset)
    val_steps = cfg.val_steps or None

    torch.manual_seed(cfg.seed)
    mcfg = cfg.model_config(spec.n_feature + len(cfg.play) * spec.n_joint, spec.n_joint)
    ts: dict[str, Any] | None = None
    history: list[dict[str, Any]] = []
    if resume is not None:
        ck = read_checkpoint(resume)
        old = surrogate_from_dict(ck, where=str(resume))
        if old.model_cfg != mcfg:
            raise CheckpointError(
                f"{resume}: architecture {old.model_cfg.to_dict()} differs from the config's {mcfg.to_dict()}; "
                "resume with the same window/hidden/layers/cell"
            )
        if old.spec.names != spec.names:
            raise CheckpointError(
                f"{resume}: joints {list(old.spec.names)} differ from the dataset's {list(spec.names)}"
            )
        net, norm, spec = old.net, old.norm, old.spec
        ts = ck.get("train_state")
        history = list(ck.get("history") or [])
    else:
        if cfg.end_stops:
            spec, bounds = fill_envelope(
                spec, train_eps, limit_margin=cfg.limit_margin, speed_margin=cfg.speed_margin
            )
            for name, b in bounds.items():
                got = [
                    k for k in ("theta_min", "theta_max", "omega_max") if b[f"{k}_source"] == "data"
                ]
                if got:
                    say(
                        f"{name}: {', '.join(f'{k} {b[k]:.4g}' for k in got)} from the training data"
                    )
        norm = Normalization.fit(
            [e.theta for e in train_eps], [e.u for e in train_eps], spec, play=cfg.play
        )
        net = SurrogateNet(mcfg)
    net.to(device).train()
    sur = Surrogate(
        net=net,
        spec=spec,
        norm=norm.to(device),
        model_cfg=mcfg,
        mode=cfg.mode,
        train_config=to_dict(cfg),
        metrics={},
        name=cfg.cell,
        end_stops=cfg.end_stops,
    )
    data = _make_data(train_eps, norm, device)

    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    ema_sur: Surrogate | None = None
    if cfg.ema_decay > 0:
        ema = torch.optim.swa_utils.AveragedModel(
            net, multi_avg_fn=torch.optim.swa_utils.get_ema_multi_avg_fn(cfg.ema_decay)
        )
        opt.register_step_post_hook(lambda *_: ema.update_parameters(net))
        ema_sur = replace(sur, net=ema.module)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
        opt, mode="min", factor=cfg.plateau_factor, patience=cfg.plateau_patience, min_lr=cfg.min_lr
    )
    start_epoch, best_val, bad, elapsed0 = 0, math.inf, 0, 0.0
    if ts:
        try:
            opt.load_state_dict(ts["optimizer"])
            sched.load_state_dict(ts["scheduler"])
        except (KeyError, ValueError, TypeError) as e:
            raise CheckpointError(
                f"{resume}: optimiser state does not fit ({e}); resume from a matching last.pt"
            ) from e
        start_epoch = int(ts["epoch"]) + 1
        best_val = float(ts["best_val"])
        bad = int(ts["bad_epochs"])
        elapsed0 = float(ts.get("elapsed_s", 0.0))
        say(f"resuming from {resume} at epoch {start_epoch} (best val_error {best_val:.4g})")

    if main:
        write_text(out / "config.toml", dumps_toml({"train": to_dict(cfg)}))
    tb = _tb_writer(out, cfg.tensorboard) if main else None
    t_start = time.monotonic() - elapsed0
    budget = cfg.max_train_seconds if cfg.max_train_seconds > 0 else math.inf
    deadline = t_start + budget
    par: _Par | None = None
    if dist is not None:
        par = _Par(ctx=dist, net=dist.wrap(net), timed=math.isfinite(budget))
    show = (
        (lambda it, **kw: it)
        if show_progress is False or not main
        else (
            lambda it, **kw: progress(
                it, disable=None if show_progress is None else not show_progress, **kw
            )
        )
    )
    best_path, last_path = out / "best.pt", out / "last.pt"
    n_param = sum(p.numel() for p in net.parameters())
    say(
        f"training {cfg.cell} ({n_param} parameters, {cfg.mode}) on {len(train_eps)} episode(s) "
        f"/ {data.x.shape[0]} samples; validating on {len(val_eps)} episode(s)"
    )
    if dist is not None:
        per = cfg.batch_size if cfg.mode == "windowed" else cfg.seq_batch
        say(
            f"data parallel: {dist.world_size} ranks x batch {per} = global {per * dist.world_size}"
        )
    try:
        for epoch in range(start_epoch, cfg.epochs):
            rng = np.random.default_rng([cfg.seed, epoch])
            net.train()
            t0 = time.monotonic()
            lr_at = _lr_fn(cfg, epoch, t_start, budget)
            if par is not None and par.timed and cfg.lr_schedule == "cosine":
                lr_at = par.rank0_lr(lr_at)  # the wall-time lr must be the same on every rank
            if cfg.mode == "windowed":
                loss, n = _epoch_windowed(sur, data, opt, cfg, rng, deadline, show, lr_at, dist=par)
            else:
                teacher = cfg.feedback == "teacher" or epoch < cfg.teacher_epochs
                loss, n = _epoch_stateful(
                    sur, data, opt, cfg, rng, deadline, show, lr_at, teacher=teacher, dist=par
                )
            t1 = time.monotonic()
            if dist is not None:
                loss, n = dist.global_loss(loss, n)
            cands = [("raw", sur)] + ([("ema", ema_sur)] if ema_sur is not None else [])
            vals = {}
            for label, cand in cands:
                if dist is not None:
                    vals[label] = dist.broadcast(
                        free_run_error(cand, val_eps, max_steps=val_steps) if main else None
                    )
                else:
                    vals[label] = free_run_error(cand, val_eps, max_steps=val_steps)
            pick = min(vals, key=lambda k: _finite(vals[k]["val_error"]))
            val, chosen = vals[pick], dict(cands)[pick]
            t2 = time.monotonic()
            net.train()
            lr = opt.param_groups[0]["lr"]
            if cfg.lr_schedule == "plateau":
                sched.step(val["val_error"] if math.isfinite(val["val_error"]) else 1e30)
            improved = val["val_error"] < best_val * (1.0 - cfg.min_delta)
            row = {
                "epoch": epoch,
                "time_s": round(t2 - t_start, 3),
                "epoch_s": round(t1 - t0, 3),
                "val_s": round(t2 - t1, 3),
                "lr": lr,
                "train_loss": loss,
                "n_sample": n,
                "val_error": val["val_error"],
                "val_theta_r2_min": min(val["theta_r2"]),
                "best": int(improved),
            }
            if ema_sur is not None:
                row.update(
                    val_error_raw=vals["raw"]["val_error"],
                    val_error_ema=vals["ema"]["val_error"],
                    weights=pick,
                )
            history.append(row)
            if improved:
                best_val, bad = val["val_error"], 0
            else:
                bad += 1
            state = {
                "epoch": epoch,
                "optimizer": opt.state_dict(),
                "scheduler": sched.state_dict(),
                "best_val": best_val,
                "bad_epochs": bad,
                "elapsed_s": t2 - t_start,
            }
            sur.metrics = {
                "epoch": epoch,
                "val_error": val["val_error"],
                "val": val,
                "best_val_error": best_val,
                "train_loss": loss,
            }
            if improved and main:
                chosen.metrics = sur.metrics
                save_checkpoint(best_path, chosen, history=history, train_state=state)
            if main:
                save_checkpoint(last_path, sur, history=history, train_state=state)
                _write_log(out / "log.csv", history)
            if tb is not None:
                tb.add_scalar("loss/train", loss, epoch)
                tb.add_scalar("val/error", min(val["val_error"], 1e6), epoch)
                tb.add_scalar("lr", lr, epoch)
                for name, r2 in zip(spec.names, val["theta_r2"]):
                    tb.add_scalar(f"val_theta_r2/{name}", max(r2, -10.0), epoch)
                tb.flush()
            say(
                f"epoch {epoch}: loss {loss:.4g}, val_error {val['val_error']:.4g}, "
                f"min theta R2 {min(val['theta_r2']):.3f}, lr {lr:.2g}, "
                f"{'(' + pick + ' weights) ' if ema_sur is not None else ''}"
                f"{t1 - t0:.1f}+{t2 - t1:.1f} s{' *' if improved else ''}"
            )
            stop_req = bool(on_epoch(epoch, dict(row))) if on_epoch is not None and main else False
            over = time.monotonic() > deadline
            if dist is not None:  # rank 0 decides for everyone
                stop_req, over = dist.broadcast((stop_req, over))
            if stop_req:
                say(f"stopping: requested after epoch {epoch}")
                break
            if bad >= cfg.patience:
                say(f"early stop: no improvement for {bad} epochs")
                break
            if over:
                say(f"stopping: training budget of {budget:g} s used")
                break
    finally:
        if tb is not None:
            tb.close()
    if main and not best_path.exists():  # every epoch diverged: keep the last one
        save_checkpoint(best_path, sur, history=history, train_state=None)
    if dist is not None:
        dist.barrier()  # best.pt is complete before any rank returns its path
    return best_path


# ---------------------------------------------------------------------------------------------
# seed ensembles


def member_configs(cfg: TrainConfig) -> list[TrainConfig]:
    """The single-network configs of ``cfg``'s ensemble members (seeds ``seed + i``)."""
    return [
        replace(cfg, members=1, member_workers=0, seed=cfg.seed + i) for i in range(cfg.members)
    ]


def _member_job(
    index: int, cfg: TrainConfig, dataset: Dataset, out: Path
) -> tuple[str, str | None]:
    """Train one member in a worker process; returns ``(best_path, error message or None)``."""
    from ..errors import ExsurError
    from ..io_utils import set_log_tag

    set_log_tag(f"exsur member {index}")
    try:
        return str(train(cfg, dataset, out=out, show_progress=False)), None
    except ExsurError as e:  # user errors cross the process boundary as their one-line message
        return "", str(e)


def train_ensemble(
    cfg: TrainConfig, dataset: Dataset, *, out: str | Path, show_progress: bool | None = None
) -> Path:
    """Train ``cfg.members`` networks with seeds ``seed, seed + 1, ...`` and merge them.

    Each member is trained exactly as :func:`train` trains one network, into
    ``OUT/member_<i>/`` (its own ``best.pt``, ``log.csv``, selection by its own validation free
    run), in up to ``cfg.member_workers`` parallel processes.  The members' best checkpoints
    are merged by :func:`~.ensemble.merge` into ``OUT/best.pt`` (omega = the members' mean),
    whose validation free run is scored and stored in its metrics; ``OUT/log.csv`` has one row
    per member and one for the ensemble.

    Returns:
        Path of ``OUT/best.pt``.
    """
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    from ..errors import ExsurError
    from .checkpoint import load_checkpoint
    from .ensemble import merge

    _, val_eps = _episodes(cfg, dataset)  # bad data fails here, before any member starts
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cfgs = member_configs(cfg)
    dirs = [out / f"member_{i}" for i in range(cfg.members)]
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    workers = min(cfg.member_workers or cpus or 1, cfg.members)
    write_text(out / "config.toml", dumps_toml({"train": to_dict(cfg)}))
    log(
        f"seed ensemble: {cfg.members} members (seeds {cfg.seed}..{cfg.seed + cfg.members - 1}), "
        f"{workers} in parallel, into {out}/member_*"
    )
    t0 = time.monotonic()
    if workers <= 1:
        bests = [train(c, dataset, out=d, show_progress=show_progress) for c, d in zip(cfgs, dirs)]
    else:
        ctx = multiprocessing.get_context("spawn")  # no fork of a process holding torch threads
        with ProcessPoolExecutor(workers, mp_context=ctx) as pool:
            jobs = [
                pool.submit(_member_job, i, c, dataset, d)
                for i, (c, d) in enumerate(zip(cfgs, dirs))
            ]
            results = [j.result() for j in jobs]
        for i, (_, err) in enumerate(results):
            if err is not None:
                raise ExsurError(f"ensemble member {i}: {err}")
        bests = [Path(p) for p, _ in results]
    members = [load_checkpoint(b) for b in bests]
    sur = merge(members)
    sur.train_config = to_dict(cfg)
    val = free_run_error(sur, val_eps, max_steps=cfg.val_steps or None)
    rows: list[dict[str, Any]] = []
    for i, m in enumerate(members):
        mm = m.metrics or {}
        rows.append(
            {
                "member": i,
                "seed": cfgs[i].seed,
                "epoch": mm.get("epoch"),
                "val_error": mm.get("val_error"),
                "val_theta_r2_min": min((mm.get("val") or {}).get("theta_r2") or [math.nan]),
            }
        )
    rows.append(
        {
            "member": "ensemble",
            "seed": "",
            "epoch": "",
            "val_error": val["val_error"],
            "val_theta_r2_min": min(val["theta_r2"]),
        }
    )
    sur.metrics = {
        **(sur.metrics or {}),
        "val_error": val["val_error"],
        "val": val,
        "best_val_error": val["val_error"],
        "train_s": round(time.monotonic() - t0, 1),
    }
    best = save_checkpoint(out / "best.pt", sur, history=rows)
    _write_log(out / "log.csv", rows, fields=list(rows[0]))
    member_vals = ", ".join(f"{r['val_error']:.4g}" for r in rows[:-1])
    log(
        f"seed ensemble: members' val_error {member_vals}; merged {val['val_error']:.4g} "
        f"(min theta R2 {min(val['theta_r2']):.3f}) -> {best}"
    )
    return best
