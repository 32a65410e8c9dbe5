"""Hyper-parameter sweeps with Optuna: ``exsur sweep DATA --out DIR --trials N``.

Each trial samples a :class:`~excavator_surrogate.training.TrainConfig` from the search
space of a :class:`SweepConfig` (window ``W``, hidden size, layers, horizon ``H``,
``lambda_bias``, learning rate, training mode), trains it into ``DIR/trials/trial_NNNN/`` and
reports the validation free-run error after every epoch; the median pruner stops trials that
are worse than the median of earlier trials at the same epoch.  The objective is the
validation free-run error of the trial's ``best.pt`` (lower is better): the weights that ship,
averaged with the last epoch's under ``average_last``.

The study lives in an Optuna storage: SQLite ``DIR/study.db`` by default; a database URL
(``postgresql://user:pw@host/db``) lets workers on many machines join the same study
(``load_if_exists``), each running ``--trials`` trials.  ``DIR`` holds one study: another one
there is refused (:func:`~.sweep_checks.check_owner`).  When a worker finishes it writes, from
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

import contextlib
import logging
import math
import shutil
import socket
import time
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..config import PresetConfig, check_types, dumps_toml, to_dict
from ..data.dataset import Dataset, load_dataset
from ..errors import ConfigError, ExsurError
from ..io_utils import LOGGER_NAME, mark_output, recorded_path, write_text
from ..outlock import first_missing
from .sweep_checks import check_base, check_owner, default_storage, safe_url

_log = logging.getLogger(__name__)

if TYPE_CHECKING:  # optuna is an optional dependency (pip install 'excavator-surrogate[sweep]')
    import optuna

    from ..training import TrainConfig
    from .sweep_report import SweepResult

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
    """Sampler seed (set it for a reproducible single-worker sweep; leave unset for many
    workers).  A worker joining a study of N trials seeds with ``seed + N``: a resumed sweep
    goes on searching instead of repeating its first trials."""
    top: int = 5
    """Trials shown in the table and the plot."""

    def __post_init__(self) -> None:
        check_types(self, "[sweep]")  # a wrong type: one line, not a failed comparison below
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
        for name in ("epochs", "top"):
            if getattr(self, name) < 1:
                raise ConfigError(f"[sweep] {name} = {getattr(self, name)} must be >= 1")
        if not self.max_train_seconds >= 0:  # every trial would fail, and the sweep exit 0
            raise ConfigError(
                f"[sweep] max_train_seconds = {self.max_train_seconds!r} must be >= 0 "
                "(0 = unlimited; --trial-seconds)"
            )
        for name in ("pruner_startup", "pruner_warmup", "sampler_startup"):
            if getattr(self, name) < 0:
                raise ConfigError(f"[sweep] {name} = {getattr(self, name)} must be >= 0")


def _optuna() -> Any:
    try:
        import optuna
    except ImportError as e:  # pragma: no cover - optional dependency
        raise ConfigError(
            "exsur sweep needs optuna: pip install 'excavator-surrogate[sweep]'"
        ) from e
    return optuna


@contextlib.contextmanager
def _optuna_logging() -> Iterator[None]:
    """Optuna's own log lines (``A new study created``, ``Trial 0 finished``) shown from
    exsur's level up (``-q``: WARNING), Optuna's level restored afterwards."""
    optuna = _optuna()
    before = optuna.logging.get_verbosity()
    level = logging.getLogger(LOGGER_NAME).getEffectiveLevel()
    optuna.logging.set_verbosity(max(before, level))
    try:
        yield
    finally:
        optuna.logging.set_verbosity(before)


def open_study(
    *,
    storage: str,
    study_name: str,
    scfg: SweepConfig,
) -> optuna.Study:
    """Create or join (``load_if_exists``) the study at ``storage``.

    Non-SQLite databases get Optuna heartbeats, so trials of a crashed worker are marked
    failed after ``grace_period`` instead of staying RUNNING forever.  A seeded sampler
    starts from ``seed`` plus the trials already in the study (:func:`_sampler`).
    """
    optuna = _optuna()
    try:
        if storage.startswith("sqlite"):
            store: Any = storage
        else:
            with warnings.catch_warnings():  # heartbeats are "experimental" since optuna 2.9
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                store = optuna.storages.RDBStorage(storage, heartbeat_interval=60, grace_period=180)
        study = optuna.create_study(
            storage=store,
            study_name=study_name,
            direction="minimize",
            load_if_exists=True,
            sampler=_sampler(scfg, n_done=0),
            pruner=optuna.pruners.MedianPruner(
                n_startup_trials=scfg.pruner_startup, n_warmup_steps=scfg.pruner_warmup
            ),
        )
        n_done = len(study.get_trials(deepcopy=False))
        if n_done and scfg.seed is not None:  # a joined study: go on from where it is
            study.sampler = _sampler(scfg, n_done=n_done)
        return study
    except ImportError as e:
        scheme = storage.split(":", 1)[0]
        raise ConfigError(
            f"storage '{safe_url(storage)}': database driver missing ({e}); install the driver "
            f"of {scheme} (postgresql: pip install psycopg2-binary) or give another --storage"
        ) from e
    except Exception as e:
        if type(e).__module__.startswith(("sqlalchemy", "optuna")):
            first = str(e).strip().splitlines()[0][:160] if str(e).strip() else type(e).__name__
            raise ConfigError(
                f"storage '{safe_url(storage)}': cannot open the study ({first})"
            ) from e
        raise


def _sampler(scfg: SweepConfig, *, n_done: int) -> optuna.samplers.BaseSampler:
    """TPE seeded with ``seed + n_done`` (``n_done``: trials already in the study), so a
    worker that joins or resumes a seeded study does not draw its first trials again."""
    seed = None if scfg.seed is None else scfg.seed + n_done
    return _optuna().samplers.TPESampler(seed=seed, n_startup_trials=scfg.sampler_startup)


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


def base_table(base: TrainConfig | Mapping[str, TrainConfig]) -> dict[str, Any]:
    """The ``[train]`` table a sweep records: the base of one mode, with the other modes'
    knobs where they differ from their defaults (a sweep's base may set both modes' knobs:
    :meth:`~excavator_surrogate.training.TrainConfig.mode_bases` reads the table back to the
    same bases).  The mode is the one that needs fewest such knobs: a base that sets one
    mode's knobs only is a plain ``[train]`` table of that mode."""
    from ..training.config import MODE_FIELDS

    if not isinstance(base, Mapping):
        return to_dict(base)

    def others(mode: str) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for other in (m for m in base if m != mode):
            own, default = to_dict(base[other]), to_dict(type(base[other])(mode=other))
            out.update({n: own[n] for n in MODE_FIELDS[other] if own[n] != default[n]})
        return out

    mode = min(base, key=lambda m: len(others(m)))
    return {**to_dict(base[mode]), **others(mode)}


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
        try:
            best = train(cfg, self.dataset, out=tdir, show_progress=False, on_epoch=on_epoch)
        except ExsurError as e:  # the user's data or config: one line, the trial FAILs (NaN)
            trial.set_user_attr("error", str(e))
            _log.warning(f"trial {trial.number} failed: {e}")
            return math.nan
        metrics = read_checkpoint(best).get("metrics") or {}
        last = tdir / "last.pt"
        history = (read_checkpoint(last) if last.is_file() else {}).get("history") or []
        # the error of the weights best.pt holds (average_last: the average's, not the
        # selected epoch's; select_smooth: the epoch's own, not the smoothed score)
        value = float(metrics.get("val_error", math.inf))
        trial.set_user_attr("checkpoint", str(best.resolve()))
        trial.set_user_attr("best_epoch", metrics.get("epoch"))
        trial.set_user_attr("epochs_run", len(history))
        trial.set_user_attr("budget_cut", bool((metrics.get("training") or {}).get("budget_cut")))
        trial.set_user_attr("seconds", round(time.monotonic() - t0, 2))
        if state["pruned_at"] is not None:
            raise optuna.TrialPruned(f"pruned after epoch {state['pruned_at']}")
        return value if math.isfinite(value) else _CAP


def _fmt_params(p: Mapping[str, Any]) -> str:
    def one(v: Any) -> str:
        return f"{v:.3g}" if isinstance(v, float) else str(v)

    return ", ".join(f"{k}={one(v)}" for k, v in p.items())


@_optuna_logging()  # -q: no INFO lines of Optuna either
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
    overwrite: bool = False,
) -> SweepResult:
    """Run ``trials`` trials of the study (joining it if it exists), then write the report.

    ``out`` holds one study's sweep: another study (or the same name in another database)
    is refused there (:func:`~.sweep_checks.check_owner`) unless ``overwrite``.

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
        overwrite: write into ``out`` even if it holds another study's sweep (``--overwrite``:
            this study's trials then replace that one's trial folders of the same numbers).

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
    storage = storage or default_storage(out)
    check_owner(out, study_name=study_name, storage=storage, overwrite=overwrite)
    new = first_missing(out)
    mark_output(out, "sweep")
    try:
        dataset = data if isinstance(data, Dataset) else load_dataset(data, splits=("train", "val"))
        check_base(base, dataset.spec)  # one line before any trial, not one per trial
        study = open_study(storage=storage, study_name=study_name, scfg=scfg)
    except BaseException:  # no trial ran: leave no folder behind that only holds the marker
        if new is not None:
            shutil.rmtree(new, ignore_errors=True)
        raise
    command = {
        "name": "sweep",
        "dataset": recorded_path(dataset.root, out) if dataset.root is not None else None,
        "trials": trials,
        "study": study_name,
        "storage": safe_url(storage),
        "timeout": timeout,
    }
    record = {"train": base_table(base), "sweep": to_dict(scfg), "command": command}
    write_text(out / "config.toml", dumps_toml(to_dict(record)))  # before the first trial
    _log.info(f"sweep: study '{study_name}' at {safe_url(storage)}; running {trials} trial(s)")
    study.optimize(
        _Objective(dataset, base, scfg, out),
        n_trials=trials,
        timeout=timeout,
        catch=(ExsurError,),
        gc_after_trial=True,
    )
    from .sweep_report import write_report  # imports optuna, which _optuna() found

    return write_report(study, out=out, storage=safe_url(storage), top=scfg.top)
