"""The human-readable import summary (Markdown), rendered from the JSON report."""

from __future__ import annotations

from typing import Any


def render_markdown(report: dict[str, Any]) -> str:
    """A short Markdown summary of an import report: what was imported, dropped and why."""
    spec = report["spec"]
    joints = spec["joints"]
    tot = report["totals"]
    names = ", ".join(
        j["name"]
        + (" (periodic)" if j["periodic"] else "")
        + (f" (linear, {j.get('unit')})" if j.get("kind") == "linear" else "")
        for j in joints
    )
    lines = [
        f"# exsur import: {spec['name']}",
        "",
        f"- joints ({len(joints)}): {names}",
        *(
            [
                f"- exogenous inputs ({len(ins)}): "
                + ", ".join(f"{i['name']} [{i['unit']}]" for i in ins)
            ]
            if (ins := spec.get("inputs"))
            else []
        ),
        f"- rate: {spec['rate_hz']:g} Hz; mapping: {report.get('mapping')}",
        f"- files: {tot['files']} ({tot['files_imported']} imported, {tot['files_dropped']} dropped, "
        f"{tot['files_failed']} failed); rows read: {tot['rows_in']}",
        f"- episodes: {tot['episodes']} (train {tot['episodes_per_split']['train']}, "
        f"val {tot['episodes_per_split']['val']}, test {tot['episodes_per_split']['test']}); "
        f"samples: train {tot['samples_per_split']['train']}, val {tot['samples_per_split']['val']}, "
        f"test {tot['samples_per_split']['test']}",
        "",
        "| file | split | rows | input rate | episodes | samples | filled | notes |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for f in report["files"]:
        if f["status"] == "failed":
            lines.append(f"| {f['file']} | - | - | - | 0 | 0 | - | FAILED: {f['error']} |")
            continue
        series = f["series"]  # a bag's topics by name; a table's one time base alone
        rates = ", ".join(
            f"{name} {s['rate_hz']:.4g} Hz" if len(series) > 1 else f"{s['rate_hz']:.4g} Hz"
            for name, s in series.items()
        )
        segs = [s for s in f["segments"] if s["status"] == "imported"]
        filled = sum(v["values"] for v in f["filled"].values())
        notes = []
        n_gap = sum(1 for n in f["notes"] if "gap" in n)
        if n_gap:
            notes.append(f"{n_gap} gap split(s)")
        n_drop = sum(1 for s in f["segments"] if s["status"] == "dropped")
        if n_drop:
            notes.append(f"{n_drop} segment(s) dropped")
        if f["clipped"]:
            notes.append("clipped: " + ", ".join(f"{k} {v}" for k, v in f["clipped"].items()))
        for joint, counts in f.get("outliers", {}).items():
            notes.append(
                f"outliers {joint}: "
                + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in counts.items())
            )
        notes.extend(n for n in f["notes"] if "upsampled" in n)
        lines.append(
            f"| {f['file']} | {f.get('split', '-')} | {f['rows']} | {rates} | {len(segs)} | "
            f"{sum(s['n_step'] for s in segs)} | {filled} | {'; '.join(notes)} |"
        )
    if report["dropped"]:
        lines += ["", "Dropped:"]
        for d in report["dropped"]:
            lines.append(
                f"- {d['file']} {d['episode']} (t {d['t_start_s']:.3f}-{d['t_end_s']:.3f} s): {d['reason']}"
            )
    if report["warnings"]:
        lines += ["", "Warnings:"]
        lines += [f"- {w}" for w in report["warnings"]]
    if report.get("out"):
        lines += ["", "Wrote this dataset folder (manifest.json, episodes/, import_report.json)."]
    else:
        lines += ["", "Dry run: nothing written."]
    return "\n".join(lines) + "\n"
