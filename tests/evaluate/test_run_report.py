"""The ``report.md`` of ``exsur run`` (evaluate.run_report): sections that depend on the run."""

from __future__ import annotations

from excavator_surrogate.evaluate.run_report import ReportContext, render_run_report

METRICS = {"theta": {}, "omega": {}, "run": {"checkpoint": "model/best.pt"}}


def _files_line(**kw) -> str:
    ctx = ReportContext(name="x", spec_names=("boom",), table_md="", **kw)
    return next(s for s in render_run_report(METRICS, ctx).splitlines() if s.startswith("Files:"))


def test_files_lists_only_the_dataset_folders_the_run_wrote() -> None:
    """A run on the user's ``--data`` writes no ``data/``; the line had listed it always."""
    assert _files_line().endswith("`excavator_surrogate.surrogate.load_checkpoint`).")
    assert "data/" not in _files_line()
    assert _files_line(datasets=("data",)).endswith("load_checkpoint`), `data/`.")
    both = _files_line(datasets=("data", "data_clean"))
    assert both.endswith("load_checkpoint`), `data/`, `data_clean/`.")
