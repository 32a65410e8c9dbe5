"""Benchmark ``exsur import`` on a large CSV log.

Writes a synthetic 3-joint log (time in ms with jitter, angles in degrees, two valve duties
per joint in %; 10 columns) with ``--rows`` rows at 100 Hz, imports it to 20 Hz and
reports rows/s, side by side with pyarrow's own multi-threaded CSV reader on the same file
(the floor of any import: parsing alone).  The last line printed is one JSON object with a
``goals`` object of booleans: 1 million rows in <= 10 s (scaled to ``--rows``), and the whole
import (parse, units, resample, validate, write Parquet) within 6x the bare parse.

The same log is then written with its time grouped in thousands (``12,345.678`` ms,
``;``-separated) and imported with ``[csv] thousands = ","``: pyarrow cannot parse grouped
numbers, so every mapped column takes the text path (read as text, checked, converted).
Goals: that import within 3x a second import of the plain log (both without the first
import's module loading), and the same episodes::

    python bench/import.py                 # 1,000,000 rows
    python bench/import.py --rows 200000
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv

from excavator_surrogate.ingest import ImportOptions, import_logs, parse_mapping

JOINTS = ("boom", "arm", "bucket")
MAPPING = {
    "machine": {"name": "bench-arm3", "rate_hz": 20.0},
    "time": {"column": "t_ms", "unit": "ms"},
    "joints": [
        {
            "name": j,
            "angle": {"column": f"{j}_deg", "unit": "deg"},
            "command": {"up": f"{j}_up_pct", "down": f"{j}_down_pct", "unit": "%"},
        }
        for j in JOINTS
    ],
}


GOAL_OVER_PARSE = 6.0
"""The whole import against ``pyarrow.csv.read_csv`` of the same file."""

GOAL_GROUPED_OVER_PLAIN = 3.0
"""The import of the log with grouped thousands against that of the plain log."""


def make_log(
    path: Path, *, rows: int, rate_hz: float = 100.0, seed: int = 0, grouped: bool = False
) -> None:
    """Write the synthetic CSV log (vectorised, a few seconds for 1 M rows); ``grouped``: the
    time with thousands separators (``12,345.678``) and ``;`` between the fields."""
    rng = np.random.default_rng(seed)
    t = np.arange(rows) / rate_hz + rng.uniform(-0.001, 0.001, rows)
    t[0] = 0.0
    cols: dict[str, np.ndarray] = {"t_ms": np.round(t * 1e3, 3)}
    for i, j in enumerate(JOINTS):
        f = 0.05 * (i + 1)
        cmd = np.sin(2 * np.pi * f * t + i) * np.sign(np.sin(2 * np.pi * 0.013 * t + i))
        cols[f"{j}_deg"] = np.round(40.0 * np.sin(2 * np.pi * f * t) + rng.normal(0, 0.03, rows), 4)
        cols[f"{j}_up_pct"] = np.round(np.maximum(cmd, 0.0) * 100.0, 2)
        cols[f"{j}_down_pct"] = np.round(np.maximum(-cmd, 0.0) * 100.0, 2)
    if not grouped:
        pcsv.write_csv(pa.table(cols), path)
        return
    table = {k: pa.array(v) for k, v in cols.items()}
    table["t_ms"] = pa.array([f"{v:,.3f}" for v in cols["t_ms"]])
    pcsv.write_csv(pa.table(table), path, pcsv.WriteOptions(delimiter=";", quoting_style="none"))


def _same_episodes(a: Path, b: Path) -> bool:
    """Whether two imported datasets hold bit-identical episodes (times, angles, commands)."""
    from excavator_surrogate.data.dataset import load_dataset

    da, db = load_dataset(a), load_dataset(b)
    eps_a = [e for split in da.episodes.values() for e in split]
    eps_b = [e for split in db.episodes.values() for e in split]
    return len(eps_a) == len(eps_b) and all(
        np.array_equal(x.time, y.time)
        and np.array_equal(x.theta, y.theta)
        and np.array_equal(x.u, y.u)
        for x, y in zip(eps_a, eps_b, strict=True)
    )


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print a summary and one JSON line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--target-s", type=float, default=10.0, help="time budget for 1 M rows [s]")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="exsur-bench-import-") as tmp:
        root = Path(tmp)
        log_path = root / "big.csv"
        t0 = time.perf_counter()
        make_log(log_path, rows=args.rows)
        t_make = time.perf_counter() - t0
        size_mb = log_path.stat().st_size / 1e6
        t0 = time.perf_counter()
        pcsv.read_csv(log_path)
        t_parse = time.perf_counter() - t0
        mapping = parse_mapping(MAPPING)
        opts = ImportOptions(min_steps=40)
        t0 = time.perf_counter()
        report = import_logs([log_path], mapping, out=root / "ds", options=opts, quiet=True)
        t_import = time.perf_counter() - t0
        grouped_path = root / "grouped.csv"
        make_log(grouped_path, rows=args.rows, grouped=True)
        grouped = parse_mapping({**MAPPING, "csv": {"delimiter": ";", "thousands": ","}})
        # the plain log again, beside it: the first import above also paid the modules'
        # first loading (scipy, the Parquet writer), which this pair must not compare
        t0 = time.perf_counter()
        import_logs([log_path], mapping, out=root / "ds_again", options=opts, quiet=True)
        t_plain = time.perf_counter() - t0
        t0 = time.perf_counter()
        report_g = import_logs([grouped_path], grouped, out=root / "ds_g", options=opts, quiet=True)
        t_grouped = time.perf_counter() - t0
        same = _same_episodes(root / "ds", root / "ds_g")
    rows_per_s = args.rows / t_import
    budget = args.target_s * args.rows / 1_000_000
    samples = sum(report["totals"]["samples_per_split"].values())
    over_parse = t_import / t_parse
    print(f"wrote {args.rows} rows ({size_mb:.1f} MB CSV) in {t_make:.2f} s", file=sys.stderr)
    print(
        f"imported {args.rows} rows -> {samples} samples at 20 Hz in {t_import:.2f} s "
        f"= {rows_per_s:,.0f} rows/s (budget {budget:.2f} s: {'ok' if t_import <= budget else 'SLOW'})"
    )
    print(f"pyarrow.csv.read_csv alone: {t_parse:.2f} s; the import takes {over_parse:.1f}x that")
    samples_g = sum(report_g["totals"]["samples_per_split"].values())
    grouped_over_plain = t_grouped / t_plain
    print(
        f"with the time grouped in thousands (text path): {t_grouped:.2f} s -> {samples_g} "
        f"samples, {grouped_over_plain:.2f}x the plain import's {t_plain:.2f} s (again, warm); "
        f"the same episodes: {same}"
    )
    print(
        json.dumps(
            {
                "bench": "import",
                "rows": args.rows,
                "csv_mb": round(size_mb, 2),
                "seconds": round(t_import, 3),
                "rows_per_s": round(rows_per_s),
                "samples_out": samples,
                "parse_seconds": round(t_parse, 3),
                "import_over_parse": round(over_parse, 2),
                "plain_again_seconds": round(t_plain, 3),
                "grouped_seconds": round(t_grouped, 3),
                "grouped_over_plain": round(grouped_over_plain, 2),
                "goals": {
                    "one_million_rows_le_10s": t_import <= budget,
                    f"import_le_{GOAL_OVER_PARSE:g}x_parse": over_parse <= GOAL_OVER_PARSE,
                    f"grouped_le_{GOAL_GROUPED_OVER_PLAIN:g}x_plain": grouped_over_plain
                    <= GOAL_GROUPED_OVER_PLAIN,
                    "grouped_equals_plain": same,
                },
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
