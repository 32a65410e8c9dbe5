"""CBE evaluation API: free-run models on test episodes, score, write metrics/table/figure.

- :func:`evaluate_models`: several surrogates (LSTM, GRU, ARX ...) on the same episodes ->
  metrics per model (and the rollouts, for plotting).
- :func:`evaluate_checkpoint`: one checkpoint (+ optional comparison checkpoints and the ARX
  and structured baselines fitted on the training split) on a dataset split; writes ``metrics.json``,
  ``table.md`` and ``cbe.png`` (the first episode; ``cbe_<episode>.png`` for the further
  episodes holding the largest shares of the error, :func:`figure_episodes`) into ``out``.

``metrics.json``::

    {"omega": {"<joint>": {"rmse", "mae", "r2"}}, "theta": {...},
     "run": {checkpoint, dataset, split, reference, mode, model, n_episode, n_step_scored, warmup,
             episodes: [{name, n_step, theta_rmse: {joint}, theta_share: {joint}}], ...},
     "compare": {"<model>": {"omega": ..., "theta": ...}},      # only with baselines; a
                                    # --compare checkpoint's with its "training" record too
     "linkage": {"<joint>": {"rmse", "mae", "r2"}},  # linear joints with a linkage: angles [rad]
                                                    # (None, + unreachable, samples: strokes
                                                    # the triangle cannot reach)
     "uncertainty": {...},   # bands' coverage/width, flagged share (evaluate/uncertainty.py)
     "horizon": {...}}       # angle RMSE n s after measured starts (evaluate/horizon.py)
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from ..config import PresetConfig, check_types, record_text, to_dict
from ..data.dataset import Dataset, load_dataset
from ..data.episode import Episode
from ..errors import ConfigError, DataError, need_path
from ..io_utils import atomic_files, recorded_path, write_json, write_text
from ..outdir import check_api_out_dir
from ..spec import MachineSpec
from ..surrogate.baselines import fit_arx, fit_structured
from ..surrogate.checkpoint import check_compatible, load_checkpoint
from ..surrogate.model import Surrogate
from ..surrogate.rollout import EpisodeRollout, rollout_episodes
from ..surrogate.scores import branch_reference
from .horizon import HORIZONS_S, check_horizons, horizon_errors, horizon_markdown
from .metrics import cbe_metrics, episode_errors, regression_metrics
from .pace import pace_markdown, training_pace
from .report import episodes_markdown, linear_units, report_markdown
from .training_report import compared_budget_markdown, training_markdown
from .uncertainty import figure_bands, uncertainty_markdown, uncertainty_metrics, uncertainty_runs

_log = logging.getLogger(__name__)


STRUCTURED = "Structured"
"""The structured baseline's label in the tables and ``metrics.json``'s ``compare``."""


@dataclass(frozen=True)
class EvaluateConfig(PresetConfig, table="evaluate"):
    """CBE evaluation options (``[evaluate]`` table of a preset)."""

    split: str = "test"
    """Dataset split to evaluate on."""
    reference: Literal["measured", "true"] = "measured"
    """Compare against (and warm up from) measured ``theta`` or ground-truth ``theta_true``."""
    arx: bool = True
    """Fit the linear ARX baseline on the training split and add it to the table."""
    structured: bool = True
    """Fit the structured baseline (per joint: dead zone, gain per direction, delay, end stops
    at the training range) on the training split and add it to the table."""
    paper: bool = True
    """Show the paper's Table II values alongside (only for swing/boom/arm/bucket joints)."""
    max_steps: int = 0
    """Truncate test episodes to this many samples (0 = full length)."""
    figure: bool = True
    """Write the Figure-2-style PNG(s)."""
    max_figures: int = 4
    """At most this many episode figures."""
    num_threads: int = 1
    """Torch intra-op threads (0 keeps torch's default)."""
    horizons: tuple[float, ...] = HORIZONS_S
    """Prediction horizons [s] scored after measured starts (table, horizon.png); [] = off."""
    horizon_stride: float = 0.5
    """Seconds between two measured starts of the prediction-horizon scores."""

    def __post_init__(self) -> None:
        check_types(self, "[evaluate]")  # a wrong type: one line, not a failed comparison below
        for name in ("max_steps", "max_figures", "num_threads"):
            if getattr(self, name) < 0:
                raise ConfigError(f"[evaluate] {name} must be >= 0, got {getattr(self, name)}")
        check_horizons(self.horizons, self.horizon_stride)


def evaluate_models(
    models: Mapping[str, Surrogate],
    episodes: Sequence[Episode],
    *,
    reference: Literal["measured", "true"] = "measured",
    max_steps: int | None = None,
) -> tuple[dict[str, dict[str, Any]], dict[str, list[EpisodeRollout]]]:
    """Free-run every model on ``episodes`` and compute CBE metrics.

    Args:
        models: label -> surrogate (each rolled out in its own mode and window).
        episodes: test episodes (same machine as the models).
        reference: ``measured`` or ``true`` angles as warm-up and reference.
        max_steps: truncate episodes.

    Returns:
        ``(metrics, runs)``: label -> ``{"omega": ..., "theta": ...}``, label -> rollouts.
    """
    if not episodes:
        raise DataError(
            None, "no episodes to evaluate", fix="check the split name and the dataset manifest"
        )
    metrics: dict[str, dict[str, Any]] = {}
    runs: dict[str, list[EpisodeRollout]] = {}
    for label, sur in models.items():
        diff = sur.spec.mismatch(episodes[0].spec)
        if diff is not None:
            raise DataError(
                episodes[0].name,
                f"model '{label}' does not fit this episode ({diff}, model vs data)",
                fix="evaluate on data of the machine and rate the model was trained for",
            )
        sur.eval()
        runs[label] = rollout_episodes(sur, episodes, reference=reference, max_steps=max_steps)
    # every model is scored on the same samples: each episode from the longest warm-up (a
    # model with a shorter window would otherwise be scored on more, and easier, samples)
    for i in range(len(episodes)):
        w = max(r[i].warmup for r in runs.values())
        for r in runs.values():
            r[i] = dataclasses.replace(r[i], warmup=w)
    for label, sur in models.items():
        metrics[label] = cbe_metrics(runs[label], sur.spec)
    return metrics, runs


def baselines(
    sur: Surrogate, dataset: Dataset, *, arx: bool = True, structured: bool = True
) -> dict[str, Surrogate]:
    """The baselines ``sur`` is scored against, fitted on ``dataset``'s training split (none
    without one): ``"ARX"`` and :data:`STRUCTURED`.

    Both run in the checkpoint's envelope (``sur.spec``: the end stops and speed bounds
    training filled in from its data), as the model they are compared with does; the
    dataset's own spec may declare none, and an ARX without stops drifted thousands of
    degrees under a held command.
    """
    models: dict[str, Surrogate] = {}
    if arx and dataset.train:
        models["ARX"] = fit_arx(
            dataset.train,
            window=sur.window,
            spec=sur.spec,
            # the surrogate's features, fitted in NumPy; not its map joints: the baseline
            # is ARX on every joint, not ARX beside the recipe's static map
            norm=sur.norm.with_own(None).to("cpu"),
            val=dataset.val,
            end_stops=sur.end_stops,
        )
    if structured and dataset.train:
        models[STRUCTURED] = fit_structured(dataset.train, window=sur.window, spec=sur.spec)
    if (arx or structured) and not dataset.train:
        _log.info("no training split loaded: skipping the baselines")
    return models


def evaluate_checkpoint(
    ckpt: str | Path,
    dataset: Dataset | str | Path,
    *,
    out: str | Path,
    overwrite: bool = False,
    split: str = "test",
    reference: Literal["measured", "true"] = "measured",
    compare: Mapping[str, str | Path] | None = None,
    arx: bool = True,
    structured: bool = True,
    paper: bool = True,
    max_steps: int = 0,
    figure: bool = True,
    max_figures: int = 4,
    num_threads: int = 1,
    horizons: tuple[float, ...] = HORIZONS_S,
    horizon_stride: float = 0.5,
    device: str | torch.device = "cpu",
    root: str | Path | None = None,
) -> dict[str, Any]:
    """Evaluate a checkpoint on one split and write ``metrics.json``, ``table.md``, ``cbe.png``.

    Args:
        ckpt: surrogate checkpoint (``best.pt``).
        dataset: a loaded :class:`Dataset` or its folder.
        out: output folder (files written atomically; other files in it are left alone).  An
            existing one must be empty or exsur's own output of a kind an evaluation may
            join (docs/design.md, "The output-folder rule").
        overwrite: write into an ``out`` that exsur did not write, as ``--overwrite`` does.
        split: split to evaluate.
        reference: ``measured`` or ``true``.
        compare: extra checkpoints, label -> path (e.g. ``{"gru": ".../best.pt"}``).
        arx: also fit and evaluate the ARX baseline on the training split (ridge chosen on ``val``).
        structured: also fit and evaluate the structured baseline on the training split
            (:func:`~..surrogate.structured.fit_structured`: per joint a dead zone, a gain per
            direction and a delay, stopped at the training range; it reads no other joint and
            no exogenous input).
        paper: show the paper's Table II values alongside.
        max_steps: truncate episodes (0 = full).
        figure: write the figure(s).
        max_figures: at most this many episode figures.
        num_threads: torch intra-op threads (0 keeps torch's default).
        horizons: prediction horizons [s] scored after measured starts every
            ``horizon_stride`` s (:mod:`.horizon`; ``()``: none); in ``metrics.json``
            ``horizon``, the table and ``horizon.png``.
        horizon_stride: seconds between two such starts.
        device: where the models are rolled out (``cpu``, ``cuda[:N]``, ``auto``).
        root: the output folder the recorded ``checkpoint`` and ``dataset`` paths are
            relative to when they lie inside it (absolute otherwise; see
            :func:`~excavator_surrogate.io_utils.recorded_path`); default ``out``.

    Returns:
        The ``metrics.json`` content.
    """
    given = locals()  # every [evaluate] field is an argument: the record holds them all
    cfg = EvaluateConfig(**{f.name: given[f.name] for f in dataclasses.fields(EvaluateConfig)})
    check_api_out_dir(out, overwrite=overwrite, kind="evaluation")
    if reference not in ("measured", "true"):
        raise ConfigError(f"reference must be 'measured' or 'true', got {reference!r}")
    t0 = time.monotonic()
    if num_threads > 0:
        torch.set_num_threads(num_threads)
    from ..devices import resolve_device

    if not isinstance(dataset, Dataset):
        need_path(dataset, "dataset")  # before the checkpoint is read
    dev = resolve_device(device)
    sur = load_checkpoint(ckpt, device=dev)
    if not isinstance(dataset, Dataset):
        dataset = load_dataset(dataset)
    episodes = dataset.split(split)
    if not episodes:
        raise DataError(
            dataset.root,
            f"split '{split}' has no episodes",
            fix=f"choose a split with episodes: {_splits_with_episodes(dataset)}",
        )
    primary = sur.name.upper()
    models: dict[str, Surrogate] = {primary: sur}
    for label, path in (compare or {}).items():
        models[label] = load_checkpoint(path, device=dev)
    where = dataset.root if dataset.root is not None else "the dataset"
    check_compatible(sur.spec, dataset.spec, ckpt=ckpt, data_name=where)
    for label, path in (compare or {}).items():
        check_compatible(models[label].spec, dataset.spec, ckpt=path, data_name=where)
    models.update(
        {k: m.to(dev) for k, m in baselines(sur, dataset, arx=arx, structured=structured).items()}
    )
    metrics, runs = evaluate_models(
        models, episodes, reference=reference, max_steps=max_steps or None
    )
    main_runs = runs[primary]
    root = out if root is None else root
    run_info = {
        "checkpoint": recorded_path(ckpt, root),
        "dataset": recorded_path(dataset.root, root) if dataset.root else None,
        "split": split,
        "reference": reference,
        "model": sur.model_cfg.to_dict(),
        "mode": sur.mode,
        "n_episode": len(main_runs),
        "n_step_scored": int(sum(len(r.time) - r.warmup for r in main_runs)),
        "warmup": max(m.window for m in models.values()),  # every model scored after it
        "dt": sur.spec.dt,
        "episodes": [
            {"name": r.name, "n_step": len(r.time), **err}
            for r, err in zip(main_runs, episode_errors(main_runs, sur.spec), strict=True)
        ],
        "seconds": round(time.monotonic() - t0, 3),
        # the model trained on the episodes it is scored on: the training split, or the
        # validation runs the recipe trains on (``train_on_val``, docs/real.md)
        "in_sample": split == "train"
        or (split == "val" and bool((sur.train_config or {}).get("train_on_val", False))),
    }
    if sur.spec.any_linear:  # metrics.json is in stored units (rad, m): say which
        run_info["units"] = {
            j.name: {"theta": "m" if j.linear else "rad", "display": j.display_unit}
            for j in sur.spec.joints
        }
    result: dict[str, Any] = {**metrics[primary], "run": run_info}
    link = linkage_metrics(main_runs, sur.spec)
    if link:
        result["linkage"] = link
    result["training"] = (sur.metrics or {}).get("training")  # did the wall-time cap cut it?
    # how fast this computer trained it, from the logs beside the checkpoint (not in best.pt)
    result["pace"] = training_pace(Path(ckpt).parent) if result["training"] else None
    unc_runs = uncertainty_runs(
        sur, episodes, main_runs, reference=reference, max_steps=max_steps or None
    )
    result["uncertainty"] = uncertainty_metrics(sur, unc_runs)
    if len(models) > 1:
        result["compare"] = {k: dict(v) for k, v in metrics.items() if k != primary}
        for label in compare or {}:  # a compared checkpoint's training: did the cap cut it?
            result["compare"][label]["training"] = (models[label].metrics or {}).get("training")
    if horizons:
        result["horizon"] = horizon_errors(
            models,
            episodes,
            spec=sur.spec,
            reference=reference,
            horizons_s=horizons,
            stride_s=horizon_stride,
            max_steps=max_steps or None,
        )
    shown = figure_episodes(run_info["episodes"], max_figures) if figure else []
    names = ["cbe.png" if k == 0 else f"cbe_{main_runs[i].name}.png" for k, i in enumerate(shown)]
    out = Path(out)
    # all files or none; an earlier evaluation's episode figures go with it
    with atomic_files(out, kind="evaluation", replaces=("cbe_*.png", "horizon.png")) as tmp:
        write_json(tmp / "metrics.json", result)
        command = {
            "name": "evaluate",
            "checkpoint": run_info["checkpoint"],
            "dataset": run_info["dataset"],
            **(
                {"compare": {k: recorded_path(p, root) for k, p in compare.items()}}
                if compare
                else {}
            ),
            "device": str(device),
        }
        record = {"evaluate": to_dict(cfg), "command": to_dict(command)}
        write_text(tmp / "config.toml", record_text(out / "config.toml", record))
        write_text(
            tmp / "table.md",
            report_markdown(
                metrics, primary=primary, run=run_info, paper=paper, spec=sur.spec, linkage=link
            )
            + episodes_markdown(run_info["episodes"], spec=sur.spec, figures=names)
            + training_markdown(result["training"], spec=sur.spec)
            + compared_budget_markdown(result.get("compare") or {})
            + pace_markdown(result["pace"], result["training"])
            + "\n"
            + uncertainty_markdown(
                result["uncertainty"], sur.spec.names, units=linear_units(sur.spec)
            )
            + "\n"
            + horizon_markdown(result.get("horizon") or {}),
        )
        if figure and result.get("horizon", {}).get("n_start"):
            from ..plotting.horizon import plot_horizon

            plot_horizon(tmp / "horizon.png", result["horizon"])
        if figure:
            from ..plotting.cbe import plot_cbe

            for i, name in zip(shown, names, strict=True):
                r = main_runs[i]
                f = np.array([j.display_factor for j in sur.spec.joints])  # mm for a stroke in mm
                preds = {
                    label: (runs[label][i].omega_hat * f, runs[label][i].theta_hat * f)
                    for label in models
                }
                scores = {}  # this episode's R² per model and joint, in each panel's corner
                for label in models:
                    m = cbe_metrics([runs[label][i]], sur.spec)
                    scores[label] = (
                        [m["omega"][n]["r2"] for n in sur.spec.names],
                        [m["theta"][n]["r2"] for n in sur.spec.names],
                    )
                bands, ood = figure_bands(unc_runs[i].pred)
                bands = {k: tuple(b * f for b in v) for k, v in bands.items()} if bands else bands
                plot_cbe(
                    tmp / name,
                    time=r.time,
                    omega_ref=r.omega_ref * f,
                    theta_ref=branch_reference(r, sur.spec) * f,
                    predictions=preds,
                    names=sur.spec.names,
                    warmup=r.warmup,
                    title=f"{r.name}: closed-loop free run vs {reference} ({split})",
                    ref_label=reference,
                    bands=bands,
                    ood=ood,
                    units=_plot_units(sur.spec),
                    scores=scores,
                )
    return result


def figure_episodes(episodes: Sequence[Mapping[str, Any]], max_figures: int) -> list[int]:
    """Indices of the episodes to draw, at most ``max_figures``: the first (``cbe.png``), then
    the others by the largest share of any joint's pooled angle error they hold
    (``theta_share`` of :func:`~.metrics.episode_errors`; ties and unscored ones in order)."""
    if max_figures <= 0 or not episodes:
        return []

    def worst(e: Mapping[str, Any]) -> float:
        shares = [v for v in (e.get("theta_share") or {}).values() if v is not None]
        return max(shares, default=0.0)

    rest = sorted(range(1, len(episodes)), key=lambda i: (-worst(episodes[i]), i))
    return [0, *rest[: max_figures - 1]]


def _plot_units(spec: MachineSpec) -> list[tuple[str, str]] | None:
    """Per joint (ω unit, θ unit) for the figure's axes; None keeps the rad labels."""
    if not spec.any_linear:
        return None
    return [(j.rate_unit, j.display_unit) for j in spec.joints]


def linkage_metrics(runs: Sequence[EpisodeRollout], spec: MachineSpec) -> dict[str, Any]:
    """RMSE, MAE and R² of the joint angles [rad] that the linear joints with a linkage give
    (the free-run and reference strokes turned into angles, warm-up excluded, episodes
    pooled); empty when no joint has a linkage.

    A joint with a stroke its triangle cannot reach (:meth:`~..spec.Linkage.reachable`:
    a linkage in the wrong unit, or a free run beyond it) has no angle there: its scores are
    None, with ``unreachable`` and ``samples`` counting them (a clipped angle would score a
    linkage that fits no stroke 0.0000)."""
    out: dict[str, Any] = {}
    for k, j in enumerate(spec.joints):
        if j.linkage is None:
            continue
        hat = np.concatenate([r.theta_hat[r.warmup :, k] for r in runs])  # strokes [m]
        ref_s = np.concatenate([r.theta_ref[r.warmup :, k] for r in runs])
        far = ~(j.linkage.reachable(hat) & j.linkage.reachable(ref_s))
        if far.any():
            none = dict.fromkeys(("rmse", "mae", "r2"))
            out[j.name] = {**none, "unreachable": int(far.sum()), "samples": int(far.size)}
            continue
        pred, ref = j.linkage.angle(hat), j.linkage.angle(ref_s)
        m = regression_metrics(pred[:, None], ref[:, None])
        out[j.name] = {
            key: (float(m[key][0]) if math.isfinite(m[key][0]) else None)
            for key in ("rmse", "mae", "r2")
        }
    return out


def _splits_with_episodes(dataset: Dataset) -> list[str]:
    """The splits of ``dataset``'s manifest that hold episodes (loaded or not)."""
    listed = [e.get("split") for e in (dataset.manifest or {}).get("episodes", [])]
    loaded = [s for s, e in dataset.episodes.items() if e]
    return [s for s in ("train", "val", "test") if s in listed or s in loaded]
