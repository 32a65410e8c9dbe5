"""The epoch loop: one network, any mode, any loss, one process or many.

:func:`train_network` is the only training loop.  Per epoch it asks the mode
(:mod:`.modes`) for the epoch's batches, lets the :class:`~.parallel.Parallel` context shard
each one, feeds the mode's predictions to the loss (:mod:`.loss`) and steps under the one NaN
rule (:func:`~.parallel.clip_and_step`); then it validates (:mod:`.selection`), keeps
``best.pt`` / ``last.pt`` (:mod:`.resume` reads them back) and writes ``log.csv``
(:mod:`.records`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .. import numerics
from ..data.dataset import Dataset
from ..data.episode import Episode
from ..devices import resolve_device
from ..errors import ConfigError
from ..io_utils import mark_output, progress
from ..surrogate.checkpoint import read_checkpoint, save_checkpoint, surrogate_from_dict
from ..surrogate.features import Normalization
from ..surrogate.model import Surrogate
from ..surrogate.scores import worst_r2
from ..surrogate.validation import free_run_errors
from .batches import make_data, split_episodes
from .config import TrainConfig
from .estimate import estimate_work
from .guards import check_finite
from .ignored import narrow_episodes, widen_checkpoint, without_inputs
from .loss import LossFn, default_loss
from .modes import Mode, make_mode
from .optim import Optimisation, cosine_lr
from .parallel import LrAt, Parallel, SingleProcess, rank0_deadline
from .records import (
    budget_cut_message,
    budget_note,
    epoch_row,
    parallel_record,
    record_training,
    tb_epoch,
    tb_writer,
    training_summary,
    untimed,
    untimed_state,
    write_config,
    write_log,
)
from .resume import carry_best, fit_norm, start
from .selection import (
    averaged,
    choose,
    first_eligible,
    is_better,
    not_validated,
    selection_score,
    validation_start,
)

_log = logging.getLogger(__name__)

EpochCallback = Callable[[int, dict[str, Any]], bool]
"""``on_epoch(epoch, row) -> stop``: called after every epoch (rank 0) with the ``log.csv`` row."""


def run_epoch(
    mode: Mode,
    net: Any,
    par: Parallel,
    opt: torch.optim.Optimizer,
    *,
    epoch: int,
    rng: np.random.Generator,
    loss_fn: LossFn,
    grad_clip: float,
    lr_at: LrAt,
    past: Callable[[], bool],
    show: Callable[..., Any],
) -> tuple[float, int]:
    """Train one epoch; returns this rank's ``(mean loss per target sample, samples)``."""
    batches = mode.batches(rng, par.world_size)
    total, count = 0.0, 0
    for batch in show(batches, total=len(batches), desc="train"):
        index, weight, n_real = par.shard_batch(batch)
        for y_hat, y, n_step in mode.predict(net, index, epoch):
            loss = loss_fn(y_hat, y)
            stepped = par.backward_step(
                loss, weight=weight, net=net, opt=opt, grad_clip=grad_clip, lr_at=lr_at
            )
            if stepped and n_real:
                total += float(loss.detach()) * n_real * n_step
                count += n_real * n_step
        if past():
            break
    return (total / count if count else math.nan), count


def _progress(show_progress: bool | None, main: bool) -> Callable[..., Any]:
    if show_progress is False or not main:
        return lambda it, **kw: it
    disable = None if show_progress is None else not show_progress
    return lambda it, **kw: progress(it, disable=disable, **kw)


def train_network(
    cfg: TrainConfig,
    dataset: Dataset,
    *,
    out: str | Path,
    resume: str | Path | None = None,
    show_progress: bool | None = None,
    on_epoch: EpochCallback | None = None,
    par: Parallel | None = None,
    loss: LossFn | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train one network (see :func:`~excavator_surrogate.training.api.train`); returns ``best.pt``."""
    numerics_mode = numerics.check()  # portable: no oneDNN, pinned MKL and ATen kernels
    out = Path(out)  # marked once the resume file passed: a refused call leaves no folder
    if par is None:
        try:
            par = SingleProcess(device=resolve_device(cfg.device))
        except ConfigError as e:
            raise ConfigError(f"[train] {e}") from e
    main = par.is_main
    say = _log.info if main else (lambda msg: None)
    loss_fn = loss if loss is not None else default_loss(lambda_bias=cfg.lambda_bias)
    if cfg.num_threads > 0:
        torch.set_num_threads(cfg.num_threads)
    spec = wide_spec = dataset.spec
    train_eps, val_eps = split_episodes(cfg, dataset)
    like: Normalization | None = None  # ignored inputs: a network using them is normalised so
    if cfg.exogenous == "ignore" and spec.n_input:
        # trained as on the data that never had the inputs, stored with them (ignored.py)
        like = fit_norm(cfg, train_eps, spec)
        dataset = without_inputs(dataset)
        spec = dataset.spec
        train_eps, val_eps = (narrow_episodes(eps, spec) for eps in (train_eps, val_eps))
    val_steps = cfg.val_steps or None

    torch.manual_seed(cfg.seed)
    mcfg = cfg.model_config(cfg.n_feature(spec), spec.n_joint)
    st = start(cfg, mcfg, spec, train_eps, resume, data_name=dataset.root or "the dataset")
    if main:  # before the first file: the folder is exsur's (only rank 0 writes into it; a
        # rank that marked it raced rank 0's check of the folder, which saw its temporary file)
        mark_output(out, "model")
    net, history = st.net, st.history
    for line in st.derived:
        say(line)
    if like is not None:
        say(
            f"ignoring the exogenous inputs {list(wide_spec.u_names[spec.n_joint :])}: trained "
            "without their columns, stored with zero weights for them"
        )
    sur = st.surrogate(cfg, par.device)
    data = make_data(train_eps, st.norm, par.device)
    optim = Optimisation.build(cfg, sur)
    best_val, bad = st.best_val, st.bad_epochs
    best_path, last_path = out / "best.pt", out / "last.pt"
    if st.train_state:
        assert resume is not None
        optim.load(st.train_state, where=str(resume))
        say(f"resuming from {resume} at epoch {st.epoch} (best val_error {st.best_val:.4g})")
        keep = True  # the resumed best: rank 0 looks for its weights, every rank follows
        if main and not best_path.exists() and math.isfinite(best_val):
            keep = carry_best(resume, best_path, best_val)
            say(
                f"{best_path} starts as the resumed run's best (val_error {best_val:.4g}); "
                "an epoch that beats it replaces it"
                if keep
                else f"no best.pt of val_error {best_val:.4g} beside {resume}: the best "
                "checkpoint is chosen among this run's epochs"
            )
        if not par.broadcast(keep):
            best_val, bad = math.inf, 0

    if main:  # a resumed run records what it continued: the checkpoint and the first epoch
        if resume is not None:
            notes = {
                **(notes or {}),
                "resume": {"from": str(Path(resume).resolve()), "epoch": st.epoch},
            }
        if par.world_size > 1:  # [train] holds the per-process batch: the global one too
            notes = {**(notes or {}), "parallel": parallel_record(cfg, par.world_size)}
        write_config(out, cfg, notes=notes)
    tb = tb_writer(out, cfg.tensorboard) if main else None
    t_start = time.monotonic() - st.elapsed_s
    budget = cfg.max_train_seconds if cfg.max_train_seconds > 0 else math.inf
    past = rank0_deadline(par, t_start + budget)
    show = _progress(show_progress, main)
    mode = make_mode(cfg, data, sur)
    dnet = par.wrap(net)
    n_param = sum(p.numel() for p in net.parameters())
    say(
        f"training {cfg.cell} ({n_param} parameters, {cfg.mode}) on {len(train_eps)} episode(s) "
        f"/ {data.x.shape[0]} samples; validating on {len(val_eps)} episode(s)"
    )
    if par.world_size > 1:
        per = cfg.batch_size if cfg.mode == "windowed" else cfg.seq_batch
        say(f"data parallel: {par.world_size} ranks x batch {per} = global {per * par.world_size}")
    cands = [("raw", sur)] + ([("ema", optim.ema_sur)] if optim.ema_sur is not None else [])
    done, stopped = st.epoch, "planned"
    say(f"planned: {cfg.epochs} epochs{budget_note(budget)}")
    validate_from = validation_start(cfg)
    # the reference machine's time for an epoch's training steps (log.csv: this computer's
    # pace against it, evaluate/pace.py); NaN where the cost model does not cover the config
    ref = estimate_work(cfg, dataset, cpus=1)
    ref_epoch_s = ref.train_s if ref is not None and not ref.unmodelled else math.nan
    if validate_from > st.epoch:
        say(
            f"validating from epoch {validate_from} on: no earlier epoch competes for best.pt "
            + (
                "(train_on_val: validation is trained on, so only the last epoch competes)"
                if cfg.train_on_val
                else f"(select_after {cfg.select_after:g}, select_smooth {cfg.select_smooth})"
            )
        )
    try:
        for epoch in range(st.epoch, cfg.epochs):
            rng = np.random.default_rng([cfg.seed, epoch])
            net.train()
            t0 = time.monotonic()
            lr_at = cosine_lr(cfg, epoch)
            loss, n = run_epoch(
                mode,
                dnet,
                par,
                optim.opt,
                epoch=epoch,
                rng=rng,
                loss_fn=loss_fn,
                grad_clip=cfg.grad_clip,
                lr_at=lr_at,
                past=past,
                show=show,
            )
            t1 = time.monotonic()
            check_finite(net, epoch=epoch, lr=optim.lr)  # one line, before anything is saved
            loss, n = par.global_loss(loss, n)
            # train_on_val: an epoch the cap ends training after is the last, so it competes
            cut_here = cfg.train_on_val and epoch + 1 < cfg.epochs and t1 > t_start + budget
            if par.world_size > 1 and cfg.train_on_val:  # rank 0 decides for everyone
                cut_here = bool(par.broadcast(cut_here))
            validated = epoch >= validate_from or cut_here
            if validated:
                choice = choose(cands, val_eps, par, max_steps=val_steps)
            else:
                choice = not_validated(cands, spec.n_joint)
            val = choice.val
            t2 = time.monotonic()
            net.train()
            lr = optim.lr
            if cfg.lr_schedule == "plateau":
                optim.sched.step(val["val_error"] if math.isfinite(val["val_error"]) else 1e30)
            score = selection_score(
                [r["val_error"] for r in history] + [val["val_error"]], smooth=cfg.select_smooth
            )
            eligible = cut_here or epoch >= first_eligible(
                cfg.epochs, cfg.select_after, last_only=cfg.train_on_val
            )
            improved = eligible and is_better(score, best_val, min_delta=cfg.min_delta)
            row = epoch_row(
                epoch,
                times=(t_start, t0, t1, t2),
                ref_epoch_s=ref_epoch_s,
                lr=lr,
                loss=loss,
                n_sample=n,
                choice=choice,
                improved=improved,
                with_ema=optim.ema_sur is not None,
            )
            if cfg.select_smooth or cfg.select_after or cfg.train_on_val:
                row["select_score"] = score if eligible else math.nan
                row["validated"] = int(validated)
            history.append(row)
            if improved:
                best_val, bad = score, 0
            elif eligible:
                bad += 1
            state = {
                "epoch": epoch,
                **optim.state(),
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
            if main:
                if improved:  # no wall-clock entries: same data and seed, same bytes
                    choice.chosen.metrics = sur.metrics
                    save_checkpoint(
                        best_path,
                        choice.chosen,
                        history=untimed(history),
                        train_state=untimed_state(state),
                    )
                save_checkpoint(last_path, sur, history=history, train_state=state)
                write_log(out / "log.csv", history)
            if validated:
                tb_epoch(tb, epoch, loss=loss, val=val, lr=lr, names=spec.names)
            scores = (
                f"val_error {val['val_error']:.4g}, min theta R2 {worst_r2(val['theta_r2']):.3f}"
                if validated
                else "not validated"
            )
            picked = choice.pick if validated and optim.ema_sur is not None else ""
            say(
                f"epoch {epoch}: loss {loss:.4g}, {scores}, lr {lr:.2g}, "
                f"{'(' + picked + ' weights) ' if picked else ''}"
                f"{t1 - t0:.1f}+{t2 - t1:.1f} s{' *' if improved else ''}"
            )
            stop_req = bool(on_epoch(epoch, dict(row))) if on_epoch is not None and main else False
            # train_on_val: the cap's stop is the cut decided above (a deadline passed since
            # would stop training after an epoch nobody validated)
            over = cut_here if cfg.train_on_val else time.monotonic() > t_start + budget
            if par.world_size > 1:  # rank 0 decides for everyone
                stop_req, over = par.broadcast((stop_req, over))
            done = epoch + 1
            if stop_req:
                stopped = "requested"
                say(f"stopping: requested after epoch {epoch}")
                break
            if bad >= cfg.patience:
                stopped = "early-stop"
                say(f"early stop: no improvement for {bad} epochs")
                break
            if over and done < cfg.epochs:
                stopped = "budget"
                if main:
                    _log.warning(budget_cut_message(budget, done, cfg.epochs))
                break
    finally:
        if tb is not None:
            tb.close()
    if main and not best_path.exists():  # every epoch diverged: keep the last one
        save_checkpoint(best_path, sur, history=untimed(history), train_state=None)
    if main and cfg.average_last:
        average_with_last(best_path, sur, val_eps, max_steps=val_steps, say=say)
    if main:
        record_training(
            best_path,
            training_summary(
                cfg,
                epochs_done=done,
                stopped=stopped,
                budget=budget,
                numerics=numerics_mode,
                environment=numerics.environment(),
                world_size=par.world_size,
            ),
        )
    if main and like is not None:  # the checkpoints take the machine's whole command vector
        for path in (best_path, last_path):
            if path.exists():
                widen_checkpoint(path, spec=wide_spec, like=like)
    par.barrier()  # best.pt is complete before any rank returns its path
    return best_path


def average_with_last(
    best_path: Path,
    last: Surrogate,
    val_eps: list[Episode],
    *,
    max_steps: int | None,
    say: Callable[[str], None],
) -> None:
    """Rewrite ``best_path`` with its weights averaged with ``last``'s (:func:`averaged`),
    scored again on ``val_eps`` (its ``metrics`` are the average's), with the selected
    epoch recorded as ``metrics["averaged_with_last"]``.  A ``best.pt`` that already holds
    an average is kept: a resumed run whose later epochs did not beat the selected one
    keeps the average with the last epoch of its first part."""
    ck = read_checkpoint(best_path)  # read once: its weights, history and train state
    sel = surrogate_from_dict(ck, where=str(best_path)).to(next(last.net.parameters()).device)
    if "averaged_with_last" in sel.metrics:
        say(
            f"best.pt already averages epochs {sel.metrics['averaged_with_last']['epoch']} and "
            f"{sel.metrics['averaged_with_last']['last_epoch']}: kept"
        )
        return
    avg = averaged(sel, last)
    val = free_run_errors([avg], val_eps, max_steps=max_steps)[0] if val_eps else None
    epoch, last_epoch = sel.metrics.get("epoch"), last.metrics.get("epoch")
    avg.metrics = {
        **sel.metrics,
        "averaged_with_last": {
            "epoch": epoch,
            "last_epoch": last_epoch,
            "val_error": sel.metrics.get("val_error"),
        },
    }
    if val is not None:
        avg.metrics.update(val_error=val["val_error"], val=val)
    save_checkpoint(best_path, avg, history=ck.get("history"), train_state=ck.get("train_state"))
    note = f": val_error {val['val_error']:.4g}" if val is not None else ""
    if epoch == last_epoch:  # train_on_val: the last epoch's validated weights and its raw ones
        say(f"best.pt: the last epoch's ({epoch}) validated weights averaged with its raw{note}")
    else:
        say(f"best.pt: epoch {epoch}'s weights averaged with the last epoch's ({last_epoch}){note}")
