"""Many logs -> one dataset folder: :func:`import_logs` and the import report.

Runs :func:`~.convert.convert_log` over every source (failing, or skipping bad logs with
``on_error = "skip"``), makes episode names unique, assigns train/val/test by source file
and writes the dataset atomically together with ``import_report.json`` and
``import_report.md``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..config import to_dict
from ..data import Episode, write_dataset
from ..errors import DataError
from ..io_utils import atomic_dir, progress, write_json, write_text
from ..outdir import check_out_dir, replace_allowed
from ..spec import MachineSpec
from .convert import FileResult, convert_log
from .mapping import ImportOptions, Mapping, SplitOptions
from .readers import expand_sources, log_kind, nested_glob, nested_logs
from .report import render_markdown
from .split import assign_splits

_log = logging.getLogger(__name__)

REPORT_JSON = "import_report.json"
REPORT_MD = "import_report.md"


def import_logs(
    sources: Sequence[str | Path],
    mapping: Mapping,
    *,
    out: str | Path | None,
    options: ImportOptions | None = None,
    split: SplitOptions | None = None,
    quiet: bool = False,
    overwrite: bool = False,
    inputs: Sequence[str | Path] = (),
) -> dict[str, Any]:
    """Import logs into a dataset folder (atomically) and return the report.

    Args:
        sources: files, folders or glob patterns (see :func:`expand_sources`).
        mapping: the parsed mapping file.
        out: dataset folder, replaced only when complete; None: validate only (dry run).
        options: import options (default: the mapping's ``[import]``).
        split: split options (default: the mapping's ``[split]``).
        quiet: no progress lines on stderr.
        overwrite: ``out`` may be replaced even if exsur did not write it (``--overwrite``).
        inputs: other files read (split file); like the logs and the mapping, none may lie
            inside ``out``.

    Returns:
        The report (also written to ``out/import_report.json``).

    Raises:
        DataError: a log breaks a validation rule (nothing is written), or nothing remains.
        ConfigError: bad options, or ``out`` is not a dataset folder.
    """
    options = options or mapping.options
    split = split or mapping.split
    paths = expand_sources(sources)
    outp = Path(out) if out is not None else None
    if outp is not None:
        # the output-folder rule: no input (a log, the mapping) inside ``out``
        mapping_file = [mapping.path] if mapping.path is not None else []
        read = [*paths, *mapping_file, *map(Path, inputs)]
        check_out_dir(outp, overwrite=overwrite, inputs=read, kind="dataset")
    spec = mapping.spec(options.rate_hz)
    results, failed = _convert_all(paths, mapping, options=options, spec=spec, quiet=quiet)
    _unique_names(results)
    kept = [r for r in results if r.episodes]
    if not kept:
        reasons = [s["reason"] for r in results for s in r.entry["segments"] if s.get("reason")]
        why = reasons[0] if reasons else (failed[0]["error"] if failed else "no segments")
        raise DataError(
            outp or (paths[0] if paths else None),
            f"nothing to import: every episode was dropped (e.g. {why})",
            fix="lower --min-steps, raise --max-gap, or check the logs",
        )
    items, warnings = _split_by_file(kept, split)
    warnings += _unsearched(sources)
    report = _report(mapping, spec, options, split, results, failed, items, warnings, outp)
    md = render_markdown(report)
    if outp is not None:
        config = {
            "import": {**to_dict(options), "sources": [str(p) for p in paths]},
            "split": to_dict(split),
            "mapping": mapping.raw,
        }
        extra = {
            "source": "import",
            "import": {"mapping": report["mapping"], "totals": report["totals"]},
        }
        with (
            replace_allowed(outp) if overwrite else contextlib.nullcontext(),
            atomic_dir(outp, kind="dataset") as tmp,
        ):
            write_dataset(tmp, items, config=config, extra=extra)
            write_json(tmp / REPORT_JSON, report)
            write_text(tmp / REPORT_MD, md)
        if not quiet:
            _log.info(f"wrote {len(items)} episodes to {outp}")
    return report


def _convert_all(
    paths: list[Path],
    mapping: Mapping,
    *,
    options: ImportOptions,
    spec: MachineSpec,
    quiet: bool,
) -> tuple[list[FileResult], list[dict[str, Any]]]:
    """:func:`convert_log` on every path: the results and the report entries of the logs
    skipped (``on_error = "skip"``; otherwise the first failure is raised)."""
    results: list[FileResult] = []
    failed: list[dict[str, Any]] = []
    seen: dict[str, Path] = {}
    for p in progress(paths, total=len(paths), desc="import", disable=True if quiet else None):
        try:
            res = convert_log(p, mapping, options=options, spec=spec)
            _check_twin(res, seen)
            results.append(res)
            if not quiet:
                n_out = sum(e.n_step for e in res.episodes)
                _log.info(
                    f"{p}: {res.entry['rows']} rows -> {len(res.episodes)} episode(s), "
                    f"{n_out} samples"
                )
        except DataError as e:
            if options.on_error != "skip" or isinstance(e, ImportTwinError):
                raise
            failed.append({"file": str(p), "status": "failed", "error": str(e), "segments": []})
            if not quiet:
                _log.warning(f"skipped {p}: {e}")
    return results, failed


class ImportTwinError(DataError):
    """Two logs of one import hold the same recording (never skipped)."""


def _check_twin(res: FileResult, seen: dict[str, Path]) -> None:
    """Refuse a log whose samples equal an earlier one's (``seen``: digest -> path): one
    recording imported twice (``run.csv`` and ``run.csv.gz``, a copy in another folder) would
    be split like two, into training and test.  Not skipped by ``on_error = "skip"``."""
    first = seen.setdefault(res.digest, res.path)
    if first != res.path:
        raise ImportTwinError(
            res.path,
            f"holds the same samples as {first}: one recording imported twice can land in "
            "both training and test",
            fix="remove one of the two files, or pass only one of them",
        )


def _unique_names(results: list[FileResult]) -> None:
    """Rename episodes (and their report segments) in place so names are unique across files:
    a repeated name gets ``_2``, ``_3``, ..."""
    used: set[str] = set()
    for r in results:
        for i, ep in enumerate(r.episodes):
            name, k = ep.name, 2
            while name in used:
                name, k = f"{ep.name}_{k}", k + 1
            used.add(name)
            if name != ep.name:
                for seg in r.entry["segments"]:
                    if seg.get("episode") == ep.name:
                        seg["episode"] = name
                r.episodes[i] = ep.replace(name=name)


def _unsearched(sources: Sequence[str | Path]) -> list[str]:
    """A warning for each folder source whose sub-folders hold logs it did not import."""
    out = []
    for s in sources:
        p = Path(s)
        if p.is_dir() and log_kind(p) is None:
            deeper = nested_logs(p)
            if deeper:
                out.append(
                    f"{p}: its sub-folders hold {len(deeper)} log(s) that were not imported (a "
                    "folder is not searched recursively); give the sub-folders too, or "
                    + nested_glob(p, deeper)
                )
    return out


def _split_by_file(
    kept: list[FileResult], split: SplitOptions
) -> tuple[list[tuple[Episode, str]], list[str]]:
    """Assign each file (all its episodes) to a split, noted in its report entry:
    ``(episode, split)`` pairs and the warnings of :func:`assign_splits`."""
    splits, warnings = assign_splits(
        [str(r.path) for r in kept], [sum(e.n_step for e in r.episodes) for r in kept], split
    )
    items: list[tuple[Episode, str]] = []
    for r in kept:
        s = splits[str(r.path)]
        r.entry["split"] = s
        for seg in r.entry["segments"]:
            if seg["status"] == "imported":
                seg["split"] = s
        items.extend((ep, s) for ep in r.episodes)
    return items, warnings


def _report(
    mapping: Mapping,
    spec: MachineSpec,
    options: ImportOptions,
    split: SplitOptions,
    results: list[FileResult],
    failed: list[dict[str, Any]],
    items: list[tuple[Episode, str]],
    warnings: list[str],
    out: Path | None,
) -> dict[str, Any]:
    files = [r.entry for r in results] + failed
    dropped = [
        {"file": e["file"], **s}
        for e in files
        for s in e.get("segments", [])
        if s["status"] == "dropped"
    ]
    n_samples = {s: sum(ep.n_step for ep, sp in items if sp == s) for s in ("train", "val", "test")}
    return {
        "report_version": 1,
        # the dataset folder holding this report ("." : it moves with the folder); None: dry run
        "out": "." if out is not None else None,
        "mapping": str(mapping.path) if mapping.path is not None else None,
        "spec": spec.to_dict(),
        "options": to_dict(options),
        "split": to_dict(split),
        "totals": {
            "files": len(files),
            "files_imported": sum(1 for e in files if e["status"] == "imported"),
            "files_dropped": sum(1 for e in files if e["status"] == "dropped"),
            "files_failed": len(failed),
            "rows_in": sum(int(e.get("rows", 0)) for e in files),
            "episodes": len(items),
            "segments_dropped": len(dropped),
            "episodes_per_split": {
                s: sum(1 for _, sp in items if sp == s) for s in ("train", "val", "test")
            },
            "samples_per_split": n_samples,
        },
        "files": files,
        "dropped": dropped,
        "warnings": warnings,
    }


def options_with(base: ImportOptions, **changes: Any) -> ImportOptions:
    """``base`` with the non-None ``changes`` applied (CLI overrides)."""
    return dataclasses.replace(base, **{k: v for k, v in changes.items() if v is not None})
