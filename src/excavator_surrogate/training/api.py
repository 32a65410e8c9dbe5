"""The public entry point :func:`train`: one network, or a seed ensemble of them."""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .. import numerics
from ..config import need_config
from ..data.dataset import Dataset, load_dataset
from ..devices import torch_threads, usable_cpus
from ..errors import ConfigError
from ..outdir import check_api_out_dir
from .batches import split_episodes
from .calibration import calibrate_best
from .config import TrainConfig
from .dual import train_dual_inputs
from .ensembles import train_ensemble
from .guards import check_excitation
from .jobs import TrainJob, run_jobs
from .kinds import train_choosing_kinds
from .loop import EpochCallback, train_network
from .loss import LossFn
from .map_apply import apply_map_choice
from .map_joints import map_options
from .net_gain import apply_network_gains
from .parallel import Parallel
from .variants import train_choosing_inputs

_log = logging.getLogger(__name__)


def train(
    cfg: TrainConfig,
    dataset: Dataset | str | Path,
    *,
    out: str | Path,
    overwrite: bool = False,
    resume: str | Path | None = None,
    show_progress: bool | None = None,
    on_epoch: EpochCallback | None = None,
    dist: Parallel | None = None,
    loss: LossFn | None = None,
    notes: Mapping[str, Any] | None = None,
) -> Path:
    """Train a surrogate on ``dataset.train``, select it by free-run error on ``dataset.val``.

    Writes into ``out``: ``best.pt`` (best validation free-run), ``last.pt`` (latest, for
    resuming), ``log.csv`` (one row per epoch), ``config.toml`` and ``tb/`` (TensorBoard).
    With ``cfg.members > 1``: a seed ensemble (:func:`~.ensembles.train_ensemble`); with
    ``cfg.exogenous = "choose"`` and exogenous inputs in the data: members that use them and
    members that ignore them, the better way kept, or per joint where the inputs help some
    joints only (:func:`~.variants.train_choosing_inputs`).  With
    ``cfg.static_map``, joints that the static valve map drives better on validation follow it
    (:mod:`.map_joints`).  Then ``best.pt`` gets the training data's coverage record and, for an ensemble, its
    uncertainty bands calibrated on the validation free runs (:mod:`.calibration`).  This
    process's own free runs (the merge, the choices, the bands) run with ``cfg.num_threads``
    torch threads, restored on return.

    Args:
        cfg: training options.
        dataset: episodes with ``train`` and ``val`` splits (``val`` empty: validate on train,
            with a warning), loaded or its folder.
        out: output folder (created).  An existing one must be empty or exsur's own output
            of a kind a model may join (docs/design.md, "The output-folder rule").
        overwrite: write into an ``out`` that exsur did not write, as ``--overwrite`` does
            (what is there stays, and files of the same names are replaced).
        resume: checkpoint (``last.pt`` or ``best.pt``) to continue from; architecture must match.
        show_progress: progress bar (None: only on a terminal or with ``EXSUR_PROGRESS=1``).
        on_epoch: called after every epoch (once the checkpoints are written) with the epoch and
            its ``log.csv`` row (``val_error``, ``train_loss``, ...); returning True stops training
            (sweeps prune trials this way).  With DDP it runs on rank 0 only.
        dist: data-parallel context, e.g. from :func:`excavator_surrogate.scale.ddp.init_distributed`
            (every rank calls ``train`` with the same arguments); None trains in this process.
        loss: ``loss(y_hat, y) -> scalar`` (default: :func:`~.loss.horizon_loss` with
            ``cfg.lambda_bias``).
        notes: extra tables written after ``[train]`` into ``config.toml`` (e.g. ``recipe``).

    Returns:
        Path of ``best.pt``.

    Raises:
        DataError: no usable training episodes, or no joint moves in them.
        CheckpointError: bad ``resume`` file.
        ConfigError: ``out`` breaks the output-folder rule, or bad options.
    """
    need_config(cfg, TrainConfig)
    if dist is None or dist.is_main:  # before anything is read (under the CLI: checked once)
        check_api_out_dir(out, overwrite=overwrite, kind="model")
    if not isinstance(dataset, Dataset):
        dataset = load_dataset(dataset, splits=("train", "val"))
    numerics.check()  # EXSUR_NUMERICS=portable: also the merge, map choice and calibration here
    with torch_threads(cfg.num_threads):  # this process's free runs too: one thread by default
        check_excitation(dataset)  # a split where nothing moves: one line, before any epoch
        choosing = cfg.exogenous == "choose" and dataset.spec.n_input > 0
        if cfg.members > 1 or choosing or cfg.prior_choice:  # several trainings
            for given, what in (
                (resume, "resume"),
                (dist, "data-parallel training"),
                (on_epoch, "on_epoch"),
                (loss, "a custom loss"),
            ):
                if given is not None:
                    raise ConfigError(
                        f"[train] members = {cfg.members}"
                        + (', exogenous = "choose"' if choosing else "")
                        + (", prior_choice = true" if cfg.prior_choice else "")
                        + f": {what} works per member; train each member as a single network "
                        "(members = 1"
                        + (', exogenous = "use" or "ignore"' if choosing else "")
                        + (", prior_choice = false" if cfg.prior_choice else "")
                        + ") and merge them with 'exsur merge'"
                    )
        if choosing and cfg.input_dropout > 0:  # the same networks both ways
            best = train_dual_inputs(
                cfg, dataset, out=out, show_progress=show_progress, notes=notes
            )
        elif choosing:  # the inputs first; then, with prior_choice, the kinds too
            best = train_choosing_inputs(
                cfg, dataset, out=out, show_progress=show_progress, notes=notes
            )
        elif cfg.prior_choice:
            best = train_choosing_kinds(
                cfg, dataset, out=out, show_progress=show_progress, notes=notes
            )
        elif cfg.members > 1:
            best = train_ensemble(cfg, dataset, out=out, show_progress=show_progress, notes=notes)
        else:
            best = train_network(
                cfg,
                dataset,
                out=out,
                resume=resume,
                show_progress=show_progress,
                on_epoch=on_epoch,
                par=dist,
                loss=loss,
                notes=notes,
            )
        if dist is None or dist.is_main:
            if cfg.static_map or cfg.net_val_gain:
                train_eps, val_eps = split_episodes(cfg, dataset)
            if cfg.static_map:  # joints on the static valve map, if validation says so
                apply_map_choice(
                    best,
                    train_eps,
                    val_eps,
                    **map_options(cfg),
                    config=Path(best).parent / "config.toml",  # its [exogenous] note too
                )
            if cfg.net_val_gain:  # the network joints at validation's speed, if it agrees
                apply_network_gains(
                    best,
                    train_eps,
                    val_eps,
                    min_span=cfg.choice_min_span,
                    trained_on_val=cfg.train_on_val,
                    max_steps=cfg.val_steps or None,
                )
            calibrate_best(cfg, dataset, best)  # best.pt is final: coverage record, ensemble bands
        return best


def _train_job(job: TrainJob, show_progress: bool | None) -> Path:
    return train(job.cfg, job.dataset, out=job.out, show_progress=show_progress, notes=job.notes)


def side_by_side(cfgs: Sequence[TrainConfig], *, cpus: int | None = None) -> bool:
    """Whether :func:`train_parallel` trains models of configs ``cfgs`` side by side: more
    than one, every one's members fit on the ``cpus`` at once (default: those this process
    may use), all on the CPU and none with ``member_workers = 1``."""
    cpus = usable_cpus() if cpus is None else cpus
    need = sum(min(c.members, cpus) for c in cfgs)  # processes at once, members >= 1
    return (
        len(cfgs) > 1
        and need <= cpus
        and all(c.device == "cpu" and c.member_workers != 1 for c in cfgs)
    )


def train_parallel(
    jobs: Sequence[TrainJob], *, cpus: int | None = None, show_progress: bool | None = None
) -> list[Path]:
    """Train independent models (e.g. a run's LSTM and its raw-data baseline) side by side.

    They run in parallel processes when every job's ensemble members fit on the CPUs at once
    (``sum of min(members, cpus) <= cpus``; single networks on two cores: two at a time), else
    one after the other (each ensemble then spreads its own members over the CPUs; also when a
    job says ``member_workers = 1``, or trains on a GPU).  Each job
    trains exactly as :func:`train` would train it alone.

    Args:
        jobs: the trainings.
        cpus: CPUs to plan for (default: :func:`~excavator_surrogate.devices.usable_cpus`).
        show_progress: progress bars (sequential jobs only).

    Returns:
        The jobs' ``best.pt`` paths, in order.
    """
    parallel = side_by_side([j.cfg for j in jobs], cpus=cpus)
    if parallel:
        _log.info(f"training {len(jobs)} models side by side: " + ", ".join(j.tag for j in jobs))
    workers = len(jobs) if parallel else 1
    return run_jobs(_train_job, jobs, workers=workers, show_progress=show_progress)
