"""Import real machine logs (CSV, dSPACE CSV, Parquet, MDF4, ROS bags, MCAP) into exsur datasets.

A TOML mapping file (:func:`load_mapping`) describes the machine (any number of joints,
any subset periodic) and maps log columns or ROS topic fields to joint angles,
optional velocities and commands.  :func:`import_logs` validates every log, converts
units, splits episodes at time gaps, resamples them anti-aliased to the target rate,
assigns train/val/test by source file and writes a dataset folder atomically, with
``import_report.json``.  See ``docs/import.md``.
"""

from __future__ import annotations

from .convert import FileResult, convert_log
from .importer import REPORT_JSON, REPORT_MD, import_logs, options_with
from .mapping import (
    AngleMap,
    Channel,
    CommandMap,
    CsvOptions,
    ImportOptions,
    InputMap,
    JointMap,
    MachineTable,
    Mapping,
    SplitOptions,
    TimeMap,
    VelocityMap,
)
from .mapping_toml import load_mapping, parse_mapping
from .readers import expand_sources, read_log
from .report import render_markdown
from .resample import antialias_sos, decimation_factor, interval_mean, resample_smooth
from .sources import RawLog, Series
from .split import assign_splits
from .velocity import kalman_velocity

__all__ = [
    "REPORT_JSON",
    "REPORT_MD",
    "AngleMap",
    "Channel",
    "CommandMap",
    "CsvOptions",
    "FileResult",
    "ImportOptions",
    "InputMap",
    "JointMap",
    "MachineTable",
    "Mapping",
    "RawLog",
    "Series",
    "SplitOptions",
    "TimeMap",
    "VelocityMap",
    "antialias_sos",
    "assign_splits",
    "convert_log",
    "decimation_factor",
    "expand_sources",
    "import_logs",
    "interval_mean",
    "kalman_velocity",
    "load_mapping",
    "options_with",
    "parse_mapping",
    "read_log",
    "render_markdown",
    "resample_smooth",
]
