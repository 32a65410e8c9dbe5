"""What a training run writes besides checkpoints: ``config.toml``, ``log.csv``, TensorBoard."""

from __future__ import annotations

import csv
import io
import logging
import math
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..config import CAP_OPTIONS, RECORD_TABLES, dumps_toml, to_dict
from ..errors import ConfigError
from ..io_utils import write_text
from ..surrogate.checkpoint import read_checkpoint, write_checkpoint_dict
from ..surrogate.scores import worst_r2
from .config import TrainConfig
from .selection import Choice

_log = logging.getLogger(__name__)

LOG_FIELDS = (
    "epoch",
    "time_s",
    "epoch_s",
    "val_s",
    "ref_epoch_s",
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
"""Columns of a single network's ``log.csv`` (one row per epoch)."""


def epoch_row(
    epoch: int,
    *,
    times: tuple[float, float, float, float],
    ref_epoch_s: float,
    lr: float,
    loss: float,
    n_sample: int,
    choice: Choice,
    improved: bool,
    with_ema: bool,
) -> dict[str, Any]:
    """One ``log.csv`` row.  ``times``: monotonic clock at the run's start, the epoch's start,
    the end of its training and the end of its validation [s]; ``ref_epoch_s``: the
    reference machine's time for the epoch's training steps [s] (NaN: not modelled)."""
    t_start, t0, t1, t2 = times
    val = choice.val
    row: dict[str, Any] = {
        "epoch": epoch,
        "time_s": round(t2 - t_start, 3),
        "epoch_s": round(t1 - t0, 3),
        "val_s": round(t2 - t1, 3),
        "ref_epoch_s": round(ref_epoch_s, 3),
        "lr": lr,
        "train_loss": loss,
        "n_sample": n_sample,
        "val_error": val["val_error"],
        "val_theta_r2_min": worst_r2(val["theta_r2"]),
        "best": int(improved),
    }
    if with_ema:
        row.update(
            val_error_raw=choice.vals["raw"]["val_error"],
            val_error_ema=choice.vals["ema"]["val_error"],
            weights=choice.pick,
        )
    return row


def write_config(out: Path, cfg: TrainConfig, *, notes: Mapping[str, Any] | None = None) -> None:
    """``OUT/config.toml``: the ``[train]`` table that produced the run, then ``notes``' tables
    (e.g. ``[recipe]``: why the data-driven recipe chose what it did), each one of
    :data:`~excavator_surrogate.config.RECORD_TABLES`, so that the record loads back as a
    preset."""
    stray = sorted(set(notes or {}) - set(RECORD_TABLES))
    if stray:  # a programming error: the record would not load back as --preset
        raise ValueError(f"write_config: [{stray[0]}] is not one of config.RECORD_TABLES")
    write_text(out / "config.toml", dumps_toml({"train": to_dict(cfg), **(notes or {})}))


def parallel_record(cfg: TrainConfig, world_size: int) -> dict[str, Any]:
    """How a data-parallel run batched (``config.toml`` ``[parallel]``, ``best.pt``
    ``metrics.training.parallel``): ``world_size`` processes, each with ``per_rank`` of the
    mode's ``batch`` knob (``batch_size`` or ``seq_batch``), ``global_batch`` in all.  The
    global batch sets the optimisation: a rerun needs it, not only the ``[train]`` table."""
    batch = "batch_size" if cfg.mode == "windowed" else "seq_batch"
    per = int(getattr(cfg, batch))
    return {
        "world_size": int(world_size),
        "batch": batch,
        "per_rank": per,
        "global_batch": per * int(world_size),
    }


def check_parallel_replay(
    record: Mapping[str, Any], cfg: TrainConfig, *, world_size: int, where: str
) -> None:
    """Refuse to train ``cfg`` from ``record`` (a run's ``config.toml`` read as a preset) on
    ``world_size`` processes when the record's ``[parallel]`` run had another number with
    the same per-process batch: the global batch, and so the model, would differ.  A
    changed batch (``--set train.seq_batch=8``) or mode is the user's own choice.

    Raises:
        ConfigError: one line naming the record, both global batches and the two ways to
            train the recorded model.
    """
    rec = record.get("parallel")
    if not isinstance(rec, Mapping) or int(rec.get("world_size", 1)) == world_size:
        return
    n, batch = int(rec["world_size"]), str(rec["batch"])
    now = parallel_record(cfg, world_size)
    if now["batch"] != batch or now["per_rank"] != int(rec["per_rank"]):
        return
    glob = int(rec["global_batch"])
    alone = f", or give --set train.{batch}={glob // world_size}" if glob % world_size == 0 else ""
    here = f"{world_size} process{'es' if world_size > 1 else ''}"
    raise ConfigError(
        f"{where}: records a data-parallel run of {n} processes x {batch} {now['per_rank']} = "
        f"global batch {glob}; {here} would train with global batch {now['global_batch']}, "
        f"another model: launch it on {n} processes (torchrun --nproc_per_node={n}){alone}"
    )


def update_notes(path: str | Path, notes: Mapping[str, Any]) -> bool:
    """Replace tables of a run's ``config.toml`` (``path``, written by :func:`write_config`)
    with ``notes``' (e.g. ``[exogenous]`` after a later choice changed it), atomically.

    Only tables the file already has are replaced; the file is left alone if it is missing
    or has none of them.  Returns whether it was rewritten."""
    path = Path(path)
    if not path.is_file():
        return False
    tables = tomllib.loads(path.read_text(encoding="utf-8"))
    if not any(k in tables for k in notes):
        return False
    tables.update({k: v for k, v in notes.items() if k in tables})
    write_text(path, dumps_toml(tables))
    return True


def write_log(
    path: Path, history: list[dict[str, Any]], fields: Sequence[str] = LOG_FIELDS
) -> None:
    """``history`` rows as CSV with ``fields`` as columns (extra keys ignored)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(fields), extrasaction="ignore")
    w.writeheader()
    for row in history:
        w.writerow(row)
    write_text(path, buf.getvalue())


def tb_writer(out: Path, enabled: bool) -> Any:
    """A TensorBoard ``SummaryWriter`` on ``OUT/tb`` (None: disabled or not installed)."""
    if not enabled:
        return None
    try:
        from torch.utils.tensorboard import SummaryWriter
    except Exception:  # tensorboard not installed: an optional extra, log.csv has the same
        _log.info("no TensorBoard logs (pip install 'excavator-surrogate[tensorboard]'): log.csv")
        return None
    return SummaryWriter(log_dir=str(out / "tb"))


def tb_epoch(
    tb: Any, epoch: int, *, loss: float, val: dict[str, Any], lr: float, names: Sequence[str]
) -> None:
    """One epoch's scalars (no-op for ``tb`` None)."""
    if tb is None:
        return
    tb.add_scalar("loss/train", loss, epoch)
    tb.add_scalar("val/error", min(val["val_error"], 1e6), epoch)
    tb.add_scalar("lr", lr, epoch)
    for name, r2 in zip(names, val["theta_r2"]):
        if not math.isnan(r2):  # NaN: a joint still in every validation run
            tb.add_scalar(f"val_theta_r2/{name}", max(r2, -10.0), epoch)
    tb.flush()


TIMING_FIELDS = ("time_s", "epoch_s", "val_s", "ref_epoch_s")
"""``log.csv`` columns of time: those that read the wall clock, and the reference machine's
time for the epoch's training steps beside them (:mod:`~excavator_surrogate.evaluate.pace`;
NaN where the cost model does not cover the config).  Kept in ``log.csv`` and ``last.pt``,
never in ``best.pt``, so the same data and seed give a bit-identical ``best.pt`` on any load."""


def untimed(history: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """``history`` without its wall-clock columns (:data:`TIMING_FIELDS`)."""
    return [{k: v for k, v in row.items() if k not in TIMING_FIELDS} for row in history]


def untimed_state(state: Mapping[str, Any]) -> dict[str, Any]:
    """A ``train_state`` without ``elapsed_s`` (a resume from ``best.pt`` restarts the budget)."""
    return {k: v for k, v in state.items() if k != "elapsed_s"}


def budget_note(budget: float) -> str:
    """``", capped at 200 s of wall time"`` (empty without a budget)."""
    return f", capped at {budget:g} s of wall time" if math.isfinite(budget) else ""


def budget_cut_message(budget: float, done: int, planned: int) -> str:
    """The one line a run logs when its wall-clock cap ends it before the planned epochs."""
    return (
        f"the wall-time cap of {budget:g} s stopped training after {done} of "
        f"{planned} planned epochs: this model depends on this computer's speed and load; "
        f"raise the cap ({CAP_OPTIONS}) to train the planned model"
    )


def training_summary(
    cfg: TrainConfig,
    *,
    epochs_done: int,
    stopped: str,
    budget: float,
    numerics: str = "native",
    environment: Mapping[str, Any] | None = None,
    world_size: int = 1,
) -> dict[str, Any]:
    """What the run did against its plan (stored in ``best.pt`` metrics as ``training``).

    ``stopped``: ``planned`` (all epochs), ``early-stop`` (patience), ``budget`` (the wall-time
    cap cut it: ``budget_cut`` is True) or ``requested`` (a callback). ``numerics``: the
    kernels it trained with (:mod:`excavator_surrogate.numerics`); ``environment``: the
    computer and libraries (:func:`excavator_surrogate.numerics.environment`), if given;
    ``world_size`` > 1: a data-parallel run, recorded as ``parallel`` (:func:`parallel_record`).
    """
    return {
        **({"environment": dict(environment)} if environment is not None else {}),
        "epochs_planned": int(cfg.epochs),
        "epochs_done": int(epochs_done),
        "stopped": stopped,
        "budget_cut": stopped == "budget",
        "max_train_seconds": float(budget) if math.isfinite(budget) else 0.0,
        "numerics": numerics,
        **({"parallel": parallel_record(cfg, world_size)} if world_size > 1 else {}),
    }


def record_training(best: Path, summary: Mapping[str, Any]) -> None:
    """Add ``summary`` to the ``training`` entry of checkpoint ``best``'s metrics, atomically."""
    ck = read_checkpoint(best)
    ck["metrics"] = {**(ck.get("metrics") or {}), "training": dict(summary)}
    write_checkpoint_dict(best, ck)
