"""Hyper-parameter sweeps with Optuna: ``exsur sweep DATA --out DIR --trials N``.

Each trial samples a :class:`~excavator_surrogate.training.TrainConfig` from the search
space of a :class:`SweepConfig` (window ``W``, hidden size, layers, horizon ``H``,
``lambda_bias``, learning rate, training mode), trains it into ``DIR/trials/trial_NNNN/`` and
reports the validation free-run error after every epoch; the median pruner stops trials that
are worse than the median of earlier trials at the same epoch.  The objective is the trial's
best validation free-run error (lower is better).

The study lives in an Optuna storage: SQLite ``DIR/study.db`` by default; a database URL
(``postgresql://user:pw@host/db``) lets workers on many machines join the same study
(``load_if_exists``), each running ``--trials`` trials.  When a worker finishes it writes, from
every trial in the study so far:

- ``DIR/sweep.md``: a Markdown table of the best trials and their parameters;
- ``DIR/sweep.png``: optimisation history + per-epoch validation curves of the best trials;
- ``DIR/sweep.json``: the same, machine-readable;
- ``DIR/best.pt``: a copy of the best trial's best checkpoint (when that file is reachable
  from this machine: trials of other machines store their checkpoint on their own disk).

The search space is the ``[sweep]`` table of a preset (ranges as ``[low, high]``; equal bounds
fix a value), on top of the preset's ``[train]`` table for everything not searched.
"""

from __future__ import annotations

import logging
import math
import re
import shutil
import socket
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..config import PresetConfig, to_dict
from ..data.dataset import Dataset, load_dataset
from ..errors import ConfigError, ExsurError
from ..io_utils import atomic_path, mark_output, write_json, write_text

_log = logging.getLogger(__name__)

if TYPE_CHECKING:  # optuna is an optional dependency (pip install 'excavator-surrogate[sweep]')
    import optuna

    from ..training import TrainConfig

_CAP = 1e6
"""Stand-in for a diverged (non-finite) validation error in reports to Optuna."""


@dataclass(frozen=True)
class SweepConfig(PresetConfig, table="sweep"):
    """Search space and per-trial budget (``[sweep]`` table of a preset).

    Ranges are ``[low, high]`` (inclusive); ``low == high`` fixes the value.
    """

    window: tuple[int, int] = (10, 40)
    """Window / warm-up length W [samples] (uniform integer)."""
    hidden: tuple[int, int] = (32, 256)
    """Recurrent width (log-uniform integer); the head's FC width follows it."""
    layers: tuple[int, int] = (1, 3)
    """Stacked recurrent layers (uniform integer)."""
    horizon: tuple[int, int] = (1, 10)
    """H, rollout steps of the windowed loss (uniform integer; windowed trials only)."""
    lambda_bias: tuple[float, float] = (0.0, 1.0)
    """Weight of the mean-bias penalty (uniform)."""
    lr: tuple[float, float] = (1e-4, 3e-3)
    """Adam learning rate (log-uniform)."""
    mode: tuple[str, ...] = ("windowed", "stateful")
    """Training modes to choose from."""
    epochs: int = 20
    """Maximum epochs per trial (also the pruner's step axis)."""
    max_train_seconds: float = 0.0
    """Wall-time budget per trial incl. validation [s] (0 = unlimited)."""
    pruner_startup: int = 4
    """Trials that finish before any trial is pruned."""
    pruner_warmup: int = 2
    """Epochs of every trial that are never pruned."""
    sampler_startup: int = 10
    """Random trials before TPE starts modelling the space."""
    seed: int | None = None
    """Sampler seed (set it for a reproducible single-worker sweep; leave unset for many workers)."""
    top: int = 5
    """Trials shown in the table and the plot."""

    def __post_init__(self) -> None:
        for name, lo_min in (("window", 1), ("hidden", 1), ("layers", 1), ("horizon", 1)):
            lo, hi = getattr(self, name)
            if not (lo_min <= lo <= hi):
                raise ConfigError(f"[sweep] {name} = [{lo}, {hi}] needs {lo_min} <= low <= high")
        lo, hi = self.lambda_bias
        if not 0 <= lo <= hi:
            raise ConfigError(f"[sweep] lambda_bias = [{lo}, {hi}] needs 0 <= low <= high")
        lo, hi = self.lr
        if not 0 < lo <= hi:
            raise ConfigError(f"[sweep] lr = [{lo}, {hi}] needs 0 < low <= high")
        bad = [m for m in self.mode if m not in ("windowed", "stateful")]
        if not self.mode or bad:
            raise ConfigError(
                f"[sweep] mode must list windowed and/or stateful, got {list(self.mode)}"
            )
        if self.epochs < 1 or self.top < 1:
            raise ConfigError("[sweep] epochs and top must be >= 1")
        if not self.max_train_seconds >= 0:  # every trial would fail, and the sweep exit 0
            raise ConfigError(
                f"[sweep] max_train_seconds = {self.max_train_seconds!r} must be >= 0 "
                "(0 = unlimited; --trial-seconds)"
            )
        if self.pruner_startup < 0 or self.pruner_warmup < 0 or self.sampler_startup < 0:
            raise ConfigError("[sweep] pruner_startup, pruner_warmup, sampler_startup must be >= 0")


@dataclass
class SweepResult:
    """What a sweep worker leaves behind (all trials of the study, not only its own)."""

    study_name: str
    storage: str
    n_complete: int
    n_pruned: int
    n_fail: int
    best_value: float | None
    """Best validation free-run error of the study (None: no trial completed)."""
    best_params: dict[str, Any] = field(default_factory=dict)
    best_trial: int | None = None
    best_checkpoint: Path | None = None
    """``DIR/best.pt`` if the best trial's checkpoint could be copied, else None."""
    table: Path | None = None
    plot: Path | None = None


def _optuna() -> Any:
    try:
        import optuna
    except ImportError as e:  # pragma: no cover - optional dependency
        raise ConfigError(
            "exsur sweep needs optuna: pip install 'excavator-surrogate[sweep]'"
        ) from e
    return optuna


def safe_url(url: str) -> str:
    """``url`` with any password replaced by ``***`` (for logs and reports)."""
    return re.sub(r"(://[^:/@]+):.*@", r"\1:***@", url)


def default_storage(out: str | Path) -> str:
    """SQLite URL of ``out/study.db``."""
    return f"sqlite:///{(Path(out) / 'study.db').resolve()}"


def open_study(
    *,
    storage: str,
    study_name: str,
    scfg: SweepConfig,
) -> optuna.Study:
    """Create or join (``load_if_exists``) the study at ``storage``.

    Non-SQLite databases get Optuna heartbeats, so trials of a crashed worker are marked
    failed after ``grace_period`` instead of staying RUNNING forever.
    """
    optuna = _optuna()
    try:
        if storage.startswith("sqlite"):
            store: Any = storage
        else:
            with warnings.catch_warnings():  # heartbeats are "experimental" since optuna 2.9
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                store = optuna.storages.RDBStorage(storage, heartbeat_interval=60, grace_period=180)
        return optuna.create_study(
            storage=store,
            study_name=study_name,
            direction="minimize",
            load_if_exists=True,
            sampler=optuna.samplers.TPESampler(
                seed=scfg.seed, n_startup_trials=scfg.sampler_startup
            ),
            pruner=optuna.pruners.MedianPruner(
                n_startup_trials=scfg.pruner_startup, n_warmup_steps=scfg.pruner_warmup
            ),
        )
    except (ImportError, ModuleNotFoundError) as e:
        raise ConfigError(
            f"storage '{safe_url(storage)}': database driver missing ({e}); e.g. pip install psycopg2-binary"
        ) from e
    except Exception as e:
        if type(e).__module__.startswith(("sqlalchemy", "optuna")):
            first = str(e).strip().splitlines()[0][:160] if str(e).strip() else type(e).__name__
            raise ConfigError(
                f"storage '{safe_url(storage)}': cannot open the study ({first})"
            ) from e
        raise


def suggest(trial: optuna.Trial, scfg: SweepConfig) -> dict[str, Any]:
    """Sample the searched ``TrainConfig`` fields of one trial (fixed ranges are not searched)."""

    def i(name: str, rng: tuple[int, int], *, log: bool = False) -> int:
        lo, hi = rng
        return int(lo) if lo == hi else trial.suggest_int(name, int(lo), int(hi), log=log)

    def f(name: str, rng: tuple[float, float], *, log: bool = False) -> float:
        lo, hi = rng
        return float(lo) if lo == hi else trial.suggest_float(name, float(lo), float(hi), log=log)

    mode = scfg.mode[0] if len(scfg.mode) == 1 else trial.suggest_categorical("mode", scfg.mode)
    hidden = i("hidden", scfg.hidden, log=True)
    p: dict[str, Any] = {
        "mode": mode,
        "window": i("window", scfg.window),
        "hidden": hidden,
        "head_hidden": hidden,
        "layers": i("layers", scfg.layers),
        "lambda_bias": f("lambda_bias", scfg.lambda_bias),
        "lr": f("lr", scfg.lr, log=True),
    }
    if mode == "windowed":
        p["horizon"] = i("horizon", scfg.horizon)
    return p


def trial_config(
    base: TrainConfig | Mapping[str, TrainConfig], scfg: SweepConfig, params: Mapping[str, Any]
) -> TrainConfig:
    """The full training config of a trial: ``base`` with the sampled ``params`` and budget.

    ``base`` may hold one config per mode (:meth:`TrainConfig.mode_bases`: a ``[train]`` table
    with both modes' knobs); a single ``base`` of the other mode than the trial's gives its
    shared knobs and drops its own mode's.  Stateful trials keep ``burn_in >= window`` (the
    warm-up of their rollouts) by raising ``burn_in`` (and ``seq_len``) when needed.
    """
    params = dict(params)
    if isinstance(base, Mapping):
        mode = params.pop("mode", next(iter(base)))
        base = base[mode]
    else:
        mode = params.pop("mode", base.mode)
    cfg = replace(
        base.for_mode(mode),
        **params,
        epochs=scfg.epochs,
        max_train_seconds=scfg.max_train_seconds,
        tensorboard=False,
    )
    if cfg.mode == "stateful" and cfg.burn_in < cfg.window:
        cfg = replace(cfg, burn_in=cfg.window, seq_len=max(cfg.seq_len, cfg.window + cfg.tbptt))
    return cfg


class _Objective:
    """Train one trial; report per-epoch validation error; prune through ``train``'s hook."""

    def __init__(
        self,
        dataset: Dataset,
        base: TrainConfig | Mapping[str, TrainConfig],
        scfg: SweepConfig,
        out: Path,
    ) -> None:
        self.dataset, self.base, self.scfg, self.out = dataset, base, scfg, out

    def __call__(self, trial: optuna.Trial) -> float:
        optuna = _optuna()
        from ..surrogate.checkpoint import read_checkpoint
        from ..training import train

        cfg = trial_config(self.base, self.scfg, suggest(trial, self.scfg))
        tdir = self.out / "trials" / f"trial_{trial.number:04d}"
        trial.set_user_attr("dir", str(tdir.resolve()))
        trial.set_user_attr("host", socket.gethostname())
        trial.set_user_attr("train", to_dict(cfg))
        state = {"pruned_at": None}

        def on_epoch(epoch: int, row: Mapping[str, Any]) -> bool:
            if not row.get("validated", 1):  # before select_after: nothing to report yet
                return False
            v = float(row["val_error"])
            trial.report(v if math.isfinite(v) else _CAP, epoch)
            if trial.should_prune():
                state["pruned_at"] = epoch
                return True
            return False

        t0 = time.monotonic()
        _log.info(f"trial {trial.number}: {_fmt_params(trial.params)}")
        best = train(cfg, self.dataset, out=tdir, show_progress=False, on_epoch=on_epoch)
        metrics = read_checkpoint(best).get("metrics") or {}
        last = tdir / "last.pt"
        history = (read_checkpoint(last) if last.is_file() else {}).get("history") or []
        value = float(metrics.get("best_val_error", metrics.get("val_error", math.inf)))
        trial.set_user_attr("checkpoint", str(best.resolve()))
        trial.set_user_attr("best_epoch", metrics.get("epoch"))
        trial.set_user_attr("epochs_run", len(history))
        trial.set_user_attr("seconds", round(time.monotonic() - t0, 2))
        if state["pruned_at"] is not None:
            raise optuna.TrialPruned(f"pruned after epoch {state['pruned_at']}")
        return value if math.isfinite(value) else _CAP


def _fmt_params(p: Mapping[str, Any]) -> str:
    def one(v: Any) -> str:
        return f"{v:.3g}" if isinstance(v, float) else str(v)

    return ", ".join(f"{k}={one(v)}" for k, v in p.items())


def run_sweep(
    data: str | Path | Dataset,
    *,
    out: str | Path,
    trials: int,
    storage: str | None = None,
    study_name: str = "exsur",
    timeout: float | None = None,
    sweep: SweepConfig | None = None,
    base: TrainConfig | Mapping[str, TrainConfig] | None = None,
) -> SweepResult:
    """Run ``trials`` trials of the study (joining it if it exists), then write the report.

    Args:
        data: dataset folder (or loaded :class:`Dataset`) with ``train`` and ``val`` splits.
        out: output folder (trial folders, ``study.db``, ``sweep.md``/``.png``/``.json``, ``best.pt``).
        trials: trials this worker runs (other workers on the same storage add theirs).
        storage: Optuna storage URL; default SQLite ``out/study.db``.
        study_name: study to create or join.
        timeout: stop starting new trials after this many seconds (None: no limit).
        sweep: search space and per-trial budget.
        base: training options that are not searched (device, batch sizes, seed ...), or one
            such config per mode (:meth:`~excavator_surrogate.training.TrainConfig.mode_bases`).

    Returns:
        The study summary.
    """
    from ..training import TrainConfig

    _optuna()  # fail early with the install hint
    if trials < 1:
        raise ConfigError(f"--trials must be >= 1, got {trials}")
    if timeout is not None and timeout <= 0:
        raise ConfigError(f"--timeout must be > 0 seconds, got {timeout}")
    scfg = sweep or SweepConfig()
    base = base or TrainConfig()
    out = Path(out)
    mark_output(out, "sweep")
    storage = storage or default_storage(out)
    dataset = data if isinstance(data, Dataset) else load_dataset(data, splits=("train", "val"))
    study = open_study(storage=storage, study_name=study_name, scfg=scfg)
    _log.info(f"sweep: study '{study_name}' at {safe_url(storage)}; running {trials} trial(s)")
    study.optimize(
        _Objective(dataset, base, scfg, out),
        n_trials=trials,
        timeout=timeout,
        catch=(ExsurError,),
        gc_after_trial=True,
    )
    return write_report(study, out=out, storage=storage, top=scfg.top)


# ---------------------------------------------------------------------------------------------
# report


def _rows(study: optuna.Study) -> list[dict[str, Any]]:
    optuna = _optuna()
    rows = []
    for t in study.get_trials(deepcopy=False):
        if t.state not in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED):
            continue
        inter = dict(sorted(t.intermediate_values.items()))
        value = t.value if t.state == optuna.trial.TrialState.COMPLETE else None
        rows.append(
            {
                "trial": t.number,
                "state": t.state.name.lower(),
                "value": value,
                "best_seen": min(inter.values()) if inter else None,
                "params": dict(t.params),
                "curve": [[int(k), float(v)] for k, v in inter.items()],
                "epochs_run": t.user_attrs.get("epochs_run", len(inter)),
                "seconds": t.user_attrs.get("seconds"),
                "checkpoint": t.user_attrs.get("checkpoint"),
                "host": t.user_attrs.get("host"),
                "train": t.user_attrs.get("train"),
            }
        )
    return rows


def _markdown(rows: list[dict[str, Any]], *, study: str, counts: dict[str, int], top: int) -> str:
    done = sorted((r for r in rows if r["value"] is not None), key=lambda r: r["value"])[:top]
    keys: list[str] = []
    for r in done:
        keys += [k for k in r["params"] if k not in keys]
    head = ["rank", "trial", "val_error", "epochs", "time [s]", *keys]
    lines = [
        f"# Sweep `{study}`",
        "",
        f"{counts['complete']} complete, {counts['pruned']} pruned, {counts['fail']} failed trials; "
        "val_error = mean over joints of free-run RMSE(θ) / std(θ) on the validation split "
        "(lower is better).",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "|".join("---" for _ in head) + "|",
    ]
    for rank, r in enumerate(done, 1):
        cells = [
            str(rank),
            str(r["trial"]),
            f"{r['value']:.4g}",
            str(r["epochs_run"]),
            "" if r["seconds"] is None else f"{r['seconds']:.1f}",
        ]
        for k in keys:
            v = r["params"].get(k, "")
            cells.append(f"{v:.3g}" if isinstance(v, float) else str(v))
        lines.append("| " + " | ".join(cells) + " |")
    if not done:
        lines.append("| – | no completed trial yet | | | |")
    return "\n".join(lines) + "\n"


def _plot(path: Path, rows: list[dict[str, Any]], *, top: int, study: str) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    done = [r for r in rows if r["value"] is not None]
    pruned = [r for r in rows if r["value"] is None and r["best_seen"] is not None]
    if done:
        ax0.scatter([r["trial"] for r in done], [r["value"] for r in done], s=18, label="complete")
    if pruned:
        ax0.scatter(
            [r["trial"] for r in pruned],
            [r["best_seen"] for r in pruned],
            marker="x",
            s=18,
            color="0.6",
            label="pruned (best epoch)",
        )
    if done:
        order = sorted(done, key=lambda r: r["trial"])
        best, xs, ys = math.inf, [], []
        for r in order:
            best = min(best, r["value"])
            xs.append(r["trial"])
            ys.append(best)
        ax0.step(xs, ys, where="post", color="C3", label="best so far")
    ax0.set_xlabel("trial")
    ax0.set_ylabel("validation free-run error")
    ax0.set_yscale("log")
    ax0.set_title(f"study '{study}'")
    ax0.legend(fontsize=8)
    for k, r in enumerate(sorted(done, key=lambda r: r["value"])[:top]):
        if r["curve"]:
            e, v = zip(*r["curve"])
            ax1.plot(e, v, marker=".", label=f"#{r['trial']} ({r['value']:.3g})", color=f"C{k}")
    from matplotlib.ticker import MaxNLocator

    for ax in (ax0, ax1):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("validation free-run error")
    ax1.set_yscale("log")
    ax1.set_title(f"best {min(top, len(done))} trials")
    if done:
        ax1.legend(fontsize=8)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def write_report(
    study: optuna.Study, *, out: str | Path, storage: str, top: int = 5
) -> SweepResult:
    """Write ``sweep.md``, ``sweep.png``, ``sweep.json`` and ``best.pt`` for the whole study."""
    optuna = _optuna()
    out = Path(out)
    states = [t.state for t in study.get_trials(deepcopy=False)]
    counts = {
        "complete": sum(s == optuna.trial.TrialState.COMPLETE for s in states),
        "pruned": sum(s == optuna.trial.TrialState.PRUNED for s in states),
        "fail": sum(s == optuna.trial.TrialState.FAIL for s in states),
    }
    rows = _rows(study)
    res = SweepResult(
        study_name=study.study_name,
        storage=safe_url(storage),
        n_complete=counts["complete"],
        n_pruned=counts["pruned"],
        n_fail=counts["fail"],
        best_value=None,
    )
    if counts["complete"]:
        bt = study.best_trial
        res.best_value, res.best_params, res.best_trial = (
            float(bt.value),
            dict(bt.params),
            bt.number,
        )
        src = bt.user_attrs.get("checkpoint")
        if src and Path(src).is_file():
            with atomic_path(out / "best.pt") as tmp:
                shutil.copyfile(src, tmp)
            res.best_checkpoint = out / "best.pt"
        else:
            _log.info(
                f"best trial {bt.number} ran on {bt.user_attrs.get('host', '?')}; its checkpoint "
                f"{src} is not reachable from here: copy it by hand"
            )
    res.table = out / "sweep.md"
    write_text(res.table, _markdown(rows, study=study.study_name, counts=counts, top=top))
    res.plot = out / "sweep.png"
    _plot(res.plot, rows, top=top, study=study.study_name)
    write_json(
        out / "sweep.json",
        {
            "study": study.study_name,
            "storage": safe_url(storage),
            **counts,
            "best": {"trial": res.best_trial, "value": res.best_value, "params": res.best_params},
            "trials": rows,
        },
    )
    _log.info(
        f"sweep: {counts['complete']} complete / {counts['pruned']} pruned / {counts['fail']} failed; "
        + (
            f"best trial {res.best_trial}: val_error {res.best_value:.4g}"
            if res.best_value is not None
            else "no completed trial"
        )
    )
    return res
