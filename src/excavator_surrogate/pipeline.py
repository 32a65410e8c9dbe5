"""``exsur run``: simulate -> [clean] -> train -> evaluate, into one report folder.

The report folder (written atomically: built in a temporary sibling, renamed when done)::

    OUT/
      report.md          # everything a person wants to read: tables, figures, timings
      metrics.json       # CBE of the LSTM (+ "compare" baselines, "cleaning", "against_cleaned")
      table.md           # the paper-layout CBE table (and baselines)
      cbe.png            # Figure-2-style closed-loop comparison
      fusion_<joint>.png # Figure-3-style Kalman fusion (Stage II presets)
      config.toml        # the resolved preset that produced the folder
      data/              # the simulated dataset (measured; with *_true columns for Stage II)
      data_clean/        # the cleaned dataset (Stage II)
      model/best.pt      # the surrogate checkpoint (+ log.csv, tb/)
      model_gru/, model_raw/   # baselines: GRU, and the LSTM trained on uncleaned data
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

from .config import dumps_toml, load_preset, merge_tables, to_dict
from .errors import ConfigError
from .io_utils import atomic_dir, log, write_json, write_text
from .stages import RunConfig, build_configs

RUN_SECTIONS = ("run", "simulate", "clean", "train", "evaluate")
"""The preset tables ``exsur run`` reads."""

DEFAULT_PRESET = "quick"
"""Preset of ``exsur run`` without ``--preset``: the README's 5-minute main job."""

# The paper's Table III (real excavator), per joint: (rmse, mae, r2).
PAPER_TABLE_III: dict[str, dict[str, dict[str, tuple[float, float, float]]]] = {
    "noload": {
        "omega": {
            "swing": (0.0481, 0.0302, 0.9755),
            "boom": (0.0342, 0.0164, 0.8487),
            "arm": (0.0941, 0.0466, 0.8841),
            "bucket": (0.1528, 0.0559, 0.5828),
        },
        "theta": {
            "swing": (0.1822, 0.1553, 0.9989),
            "boom": (0.0691, 0.0496, 0.9286),
            "arm": (0.1053, 0.0733, 0.9737),
            "bucket": (0.1200, 0.0984, 0.9706),
        },
    },
    "compound": {
        "omega": {
            "swing": (0.0249, 0.0175, 0.9750),
            "boom": (0.0259, 0.0171, 0.7920),
            "arm": (0.0269, 0.0185, 0.8734),
            "bucket": (0.0753, 0.0516, 0.8815),
        },
        "theta": {
            "swing": (0.1451, 0.1120, 0.9774),
            "boom": (0.0763, 0.0654, 0.8210),
            "arm": (0.1469, 0.1251, 0.7309),
            "bucket": (0.3395, 0.3101, 0.8667),
        },
    },
}


def run_pipeline(
    *,
    out: str | Path,
    preset: str | Path = DEFAULT_PRESET,
    data: str | Path | None = None,
    workers: int | None = None,
    seed: int | None = None,
    max_train_seconds: float | None = None,
    epochs: int | None = None,
    members: int | None = None,
    logs: Sequence[str | Path] | None = None,
    mapping: str | Path | None = None,
    sets: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, Any]:
    """Run the whole pipeline for a preset and write the report folder ``out``.

    Args:
        out: report folder (replaced only when the run completes).
        preset: shipped preset name or TOML path with ``[simulate]``, ``[train]``, ``[evaluate]``
            and optional ``[run]``/``[clean]`` tables.
        data: use this existing dataset instead of simulating (e.g. imported logs).
        workers: simulation processes (default: the preset's).
        seed: overrides the simulation and training seeds.
        max_train_seconds: overrides the training wall-time budget (per model).
        epochs: overrides the maximum number of epochs.
        members: overrides the seed-ensemble size of every trained model (1: single networks).
        logs: import these logs (files, folders, globs) with ``mapping`` instead of simulating.
        mapping: the mapping TOML of ``logs`` (see ``docs/import.md``).
        sets: further overrides by table, e.g. ``{"train": {"lr": 3e-4}}`` (``--set``; the named
            arguments above win).

    Returns:
        The content of ``metrics.json``.
    """
    from .data import load_dataset
    from .evaluate.cbe import evaluate_checkpoint
    from .simulate.generate import simulate_dataset
    from .training import train

    t_start = time.monotonic()
    if (logs is None) != (mapping is None):
        raise ConfigError("--logs and --mapping go together: give both, or neither")
    if logs is not None and data is not None:
        raise ConfigError("give either --logs (with --mapping) or --data, not both")
    raw_preset = load_preset(preset)
    name = str(raw_preset.get("name", preset))
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers}")
    named = {
        "simulate": {"workers": workers, "seed": seed},
        "train": {
            "seed": seed,
            "max_train_seconds": None if max_train_seconds is None else float(max_train_seconds),
            "epochs": epochs,
            "members": members,
        },
    }
    over = merge_tables(
        sets or {}, {k: {n: v for n, v in t.items() if v is not None} for k, t in named.items()}
    )
    cfgs = build_configs(
        raw_preset, sections=RUN_SECTIONS, overrides=over, where=f"preset '{name}'"
    )
    run_cfg: RunConfig = cfgs["run"]
    sim_cfg = cfgs["simulate"]
    train_cfg = cfgs["train"]
    recipe: list[str] = []
    eval_cfg = cfgs["evaluate"]
    timings: dict[str, float] = {}
    out = Path(out)

    with atomic_dir(out) as tmp:
        # ---- simulate (or take the user's dataset) --------------------------------------
        t0 = time.monotonic()
        if logs is not None:
            from .ingest.convert import import_logs
            from .ingest.mapping import load_mapping

            log(f"run[{name}]: import {len(logs)} source(s) with {mapping} -> {out / 'data'}")
            import_logs(list(logs), load_mapping(mapping), out=tmp / "data", quiet=True)
            data_dir = tmp / "data"
        elif data is None:
            log(f"run[{name}]: simulate -> {out / 'data'}")
            data_dir = simulate_dataset(sim_cfg, out=tmp / "data", extra={"preset": name})
        else:
            data_dir = Path(data)
            log(f"run[{name}]: using dataset {data_dir}")
        timings["import" if logs is not None else "simulate"] = time.monotonic() - t0
        raw_ds = load_dataset(data_dir)
        train_ds = raw_ds
        if run_cfg.auto_train:
            from .training.auto import auto_config

            train_cfg, recipe = auto_config(
                raw_ds, overrides=merge_tables(raw_preset.get("train", {}), over.get("train", {}))
            )
            for line in recipe:
                log(f"run[{name}]: recipe: {line}")
        if not raw_ds.split(eval_cfg.split) and raw_ds.val:
            log(
                f"run[{name}]: the dataset has no '{eval_cfg.split}' split: evaluating on 'val', "
                "which also selected the checkpoint (optimistic)"
            )
            eval_cfg = dataclasses.replace(eval_cfg, split="val")
        result_extra: dict[str, Any] = {}

        # ---- clean ----------------------------------------------------------------------
        if run_cfg.clean:
            from .clean import clean_dataset

            t0 = time.monotonic()
            log(f"run[{name}]: clean ({cfgs['clean'].method})")
            clean_dir = clean_dataset(data_dir, tmp / "data_clean", config=cfgs["clean"])
            train_ds = load_dataset(clean_dir)
            result_extra["cleaning"] = train_ds.manifest.get("cleaning", {})
            timings["clean"] = time.monotonic() - t0
            if run_cfg.fusion_figures and raw_ds.test and train_ds.test:
                from .plotting.fusion import plot_fusion

                for j in raw_ds.spec.names:
                    plot_fusion(
                        raw_ds.test[0], train_ds.test[0], joint=j, path=tmp / f"fusion_{j}.png"
                    )

        # ---- train ----------------------------------------------------------------------
        t0 = time.monotonic()
        log(f"run[{name}]: train LSTM ({train_cfg.mode})")
        best = train(train_cfg, train_ds, out=tmp / "model")
        timings["train_lstm"] = time.monotonic() - t0
        compare: dict[str, Path] = {}
        if run_cfg.gru:
            t0 = time.monotonic()
            log(f"run[{name}]: train GRU baseline")
            compare["GRU"] = train(
                dataclasses.replace(train_cfg, cell="gru"), train_ds, out=tmp / "model_gru"
            )
            timings["train_gru"] = time.monotonic() - t0
        raw_best: Path | None = None
        if run_cfg.clean and run_cfg.raw_baseline:
            t0 = time.monotonic()
            log(f"run[{name}]: train LSTM on raw (uncleaned) data")
            raw_best = train(train_cfg, raw_ds, out=tmp / "model_raw")
            timings["train_raw"] = time.monotonic() - t0

        # ---- evaluate -------------------------------------------------------------------
        t0 = time.monotonic()
        log(
            f"run[{name}]: evaluate (closed-loop free run on '{eval_cfg.split}', reference {run_cfg.reference})"
        )
        ev = dataclasses.asdict(eval_cfg)
        ev["arx"] = run_cfg.arx and ev["arx"]
        ev["paper"] = run_cfg.paper_table == "II" and ev["paper"]
        metrics = evaluate_checkpoint(
            best, train_ds, out=tmp, compare=compare, **{**ev, "reference": run_cfg.reference}
        )
        if run_cfg.clean:
            # Also score against the cleaned data (the only reference a real machine gives).
            against = evaluate_checkpoint(
                best,
                train_ds,
                out=tmp / "eval_cleaned",
                compare=None,
                **{**ev, "reference": "measured", "arx": False, "paper": False},
            )
            result_extra["against_cleaned"] = {k: against[k] for k in ("omega", "theta")}
        if raw_best is not None:
            result_extra["cleaning_effect"] = _score_against_truth(
                {"trained on cleaned": best, "trained on raw": raw_best}, train_ds, eval_cfg
            )
        if train_cfg.members > 1:
            member_paths = {
                f"member {i}": best.parent / f"member_{i}" / "best.pt"
                for i in range(train_cfg.members)
            }
            result_extra["ensemble_members"] = _score_against_truth(
                {"ensemble": best, **member_paths},
                train_ds,
                eval_cfg,
                reference=run_cfg.reference,
            )
        timings["evaluate"] = time.monotonic() - t0
        timings["total"] = time.monotonic() - t_start
        metrics.update(result_extra)
        metrics["run"] = {
            **metrics.get("run", {}),
            "preset": name,
            "split": eval_cfg.split,
            "timings_s": {k: round(v, 1) for k, v in timings.items()},
            "out": str(out),
        }
        # Paths recorded while building point into the temporary folder: point them at OUT.
        metrics = json.loads(json.dumps(metrics).replace(str(tmp), str(out)))
        for md in (tmp / "table.md", tmp / "eval_cleaned" / "table.md"):
            if md.exists():
                write_text(md, md.read_text().replace(str(tmp), str(out)))
        write_json(tmp / "metrics.json", metrics)
        # with the CLI overrides (and the data-driven recipe) applied
        used = {k: v for k, v in cfgs.items() if k != "clean" or run_cfg.clean}
        used.update(train=train_cfg, evaluate=eval_cfg)
        if logs is not None or data is not None:
            used.pop("simulate")
        record = {"name": name, **{k: to_dict(v) for k, v in used.items()}}
        if data is not None:
            record["data"] = str(data)
        if logs is not None:
            record["logs"] = {"sources": [str(p) for p in logs], "mapping": str(mapping)}
        if recipe:
            record["recipe"] = {"name": "auto", "why": recipe}
        write_text(tmp / "config.toml", dumps_toml(record))
        write_text(
            tmp / "report.md",
            render_report(
                metrics,
                name=name,
                run_cfg=run_cfg,
                spec_names=raw_ds.spec.names,
                table_md=(tmp / "table.md").read_text(),
            ),
        )
    log(f"run[{name}]: done in {timings['total']:.0f} s -> {out / 'report.md'}")
    return metrics


def _score_against_truth(
    models: Mapping[str, Path],
    ds: Any,
    eval_cfg: Any,
    *,
    reference: Literal["measured", "true"] = "true",
) -> dict[str, Any]:
    """CBE of several checkpoints on the same test episodes against ``reference`` (the truth
    by default), label -> metrics."""
    from .evaluate.cbe import evaluate_models
    from .surrogate.checkpoint import load_checkpoint

    metrics, _ = evaluate_models(
        {label: load_checkpoint(path) for label, path in models.items()},
        ds.split(eval_cfg.split),
        reference=reference,
        max_steps=eval_cfg.max_steps or None,
    )
    return metrics


def _fmt(v: Any) -> str:
    return "n/a" if v is None else f"{v:.4f}"


def render_report(
    metrics: Mapping[str, Any],
    *,
    name: str,
    run_cfg: RunConfig,
    spec_names: tuple[str, ...],
    table_md: str,
) -> str:
    """The human-readable ``report.md`` of a run."""
    from .evaluate.metrics import min_r2

    run = metrics.get("run", {})
    lines = [f"# exsur run: preset `{name}`", ""]
    th = metrics["theta"]
    om = metrics["omega"]
    worst_theta = min(v["r2"] for v in th.values() if v.get("r2") is not None)
    worst_omega = min(v["r2"] for v in om.values() if v.get("r2") is not None)
    lines += [
        f"Closed-loop free run on the {run.get('split', 'test')} split "
        f"({run.get('n_step_scored', '?')} scored steps, "
        f"reference: {run.get('reference', '?')}): **worst-joint angle R² {worst_theta:.4f}, "
        f"worst-joint ω R² {worst_omega:.4f}**.",
        "",
        *(
            [
                f"No test split: scored on the '{run.get('split')}' split, which also selected "
                "the checkpoint, so these numbers are optimistic.",
                "",
            ]
            if run.get("split", "test") != "test"
            else []
        ),
        "Timings [s]: " + ", ".join(f"{k} {v}" for k, v in run.get("timings_s", {}).items()),
        "",
        "![closed-loop comparison](cbe.png)",
        "",
    ]
    paper_key = {"III-noload": "noload", "III-compound": "compound"}.get(run_cfg.paper_table)
    if paper_key and set(spec_names) == {"swing", "boom", "arm", "bucket"}:
        ref = PAPER_TABLE_III[paper_key]
        lines += [
            f"## Against the paper's Table III ({paper_key})",
            "",
            "| Type | Joint | RMSE (ours / paper) | MAE (ours / paper) | R² (ours / paper) |",
            "|---|---|---|---|---|",
        ]
        for typ, label in (("omega", "ω"), ("theta", "θ")):
            for j in spec_names:
                m = metrics[typ][j]
                p = ref[typ][j]
                lines.append(
                    f"| {label} | {j} | {_fmt(m['rmse'])} / {p[0]:.4f} | {_fmt(m['mae'])} / {p[1]:.4f} "
                    f"| {_fmt(m['r2'])} / {p[2]:.4f} |"
                )
        lines.append("")
    if metrics.get("cleaning"):
        lines += [
            "## Cleaning (adaptive Kalman filter) against the ground truth",
            "",
            "| Joint | raw angle RMSE [rad] | fused angle RMSE [rad] | ratio | jump precision | jump recall |",
            "|---|---|---|---|---|---|",
        ]
        for j, c in metrics["cleaning"].items():
            if not isinstance(c, dict):
                continue
            lines.append(
                f"| {j} | {_fmt(c.get('rmse_raw'))} | {_fmt(c.get('rmse_fused'))} | {_fmt(c.get('rmse_ratio'))} "
                f"| {_fmt(c.get('jump_precision'))} | {_fmt(c.get('jump_recall'))} |"
            )
        lines += [""] + [f"![fusion {j}](fusion_{j}.png)" for j in spec_names] + [""]
    if "against_cleaned" in metrics:
        lines += [
            "## Surrogate CBE: against the truth vs against the cleaned data",
            "",
            "| Joint | θ R² (truth) | θ R² (cleaned) | ω R² (truth) | ω R² (cleaned) |",
            "|---|---|---|---|---|",
        ]
        ac = metrics["against_cleaned"]
        for j in spec_names:
            lines.append(
                f"| {j} | {_fmt(th[j]['r2'])} | {_fmt(ac['theta'][j]['r2'])} | {_fmt(om[j]['r2'])} "
                f"| {_fmt(ac['omega'][j]['r2'])} |"
            )
        lines.append("")
    if "cleaning_effect" in metrics:
        ce = metrics["cleaning_effect"]
        lines += [
            "## Effect of cleaning: the same LSTM trained on cleaned vs raw data (scored against the truth)",
            "",
            "| Joint | θ R² cleaned | θ R² raw | θ RMSE cleaned | θ RMSE raw | ω R² cleaned | ω R² raw |",
            "|---|---|---|---|---|---|---|",
        ]
        c, r = ce["trained on cleaned"], ce["trained on raw"]
        for j in spec_names:
            lines.append(
                f"| {j} | {_fmt(c['theta'][j]['r2'])} | {_fmt(r['theta'][j]['r2'])} | {_fmt(c['theta'][j]['rmse'])} "
                f"| {_fmt(r['theta'][j]['rmse'])} | {_fmt(c['omega'][j]['r2'])} | {_fmt(r['omega'][j]['r2'])} |"
            )
        lines.append("")
    if "ensemble_members" in metrics:
        em = metrics["ensemble_members"]
        lines += [
            "## Seed ensemble: the merged network vs its members "
            f"(scored against the {'truth' if run_cfg.reference == 'true' else 'measured data'})",
            "",
            "| Model | "
            + " | ".join(f"θ R² {j}" for j in spec_names)
            + " | worst θ R² | worst ω R² |",
            "|---|" + "---|" * (len(spec_names) + 2),
        ]
        for label, m in em.items():
            lines.append(
                f"| {label} | "
                + " | ".join(_fmt(m["theta"][j]["r2"]) for j in spec_names)
                + f" | {_fmt(min_r2(m, 'theta'))} | {_fmt(min_r2(m, 'omega'))} |"
            )
        lines.append("")
    lines += [
        "## CBE table",
        "",
        table_md.replace("# Closed-loop behavioural equivalence (CBE)", "").strip(),
        "",
    ]
    lines += [
        "Files: `metrics.json`, `table.md`, `config.toml`, `model/best.pt` (load with "
        "`excavator_surrogate.surrogate.load_checkpoint`), `data/`.",
        "",
    ]
    return "\n".join(lines)
