"""Edge cases of the command line: the entry point's exits (no command, Ctrl-C, bad numbers),
and the user-facing error branches of validate, import's split options, calibrate, info and
train.  Nothing here trains a network."""

from __future__ import annotations

import argparse
import dataclasses
import errno
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from tests.helpers.locks import lock_held_elsewhere

from excavator_surrogate.cli import cmd_validate, main
from excavator_surrogate.data import load_dataset, write_dataset, write_episode
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.synthetic import (
    synthetic_episode,
    synthetic_spec,
    synthetic_split,
)


def _last(err: str) -> str:
    return err.rstrip("\n").split("\n")[-1]


# ---- the entry point ------------------------------------------------------------------------


def test_no_command_prints_the_help_and_exits_2(cli) -> None:
    rc, out, _ = cli()
    assert rc == 2 and "usage: exsur" in out and "COMMAND" in out


def test_the_help_of_every_command_loads_no_torch() -> None:
    """A fresh interpreter builds the whole parser (every command's) and prints ``exsur
    --help``, ``exsur run --help`` and ``exsur import --help`` without importing torch, SciPy
    or MuJoCo (torch took 2-3 s of a 3-s ``--help``)."""
    code = (
        "import contextlib, io, sys\n"
        "from excavator_surrogate.cli import main\n"
        "for argv in (['--help'], ['run', '--help'], ['import', '--help']):\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "        main(argv)\n"
        "print(sorted(m for m in ('torch', 'scipy', 'mujoco') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    ).stdout
    assert out.strip() == "[]"


def test_a_seed_that_is_not_a_number_is_argparses_one_line(capsys) -> None:
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--preset", "tiny", "--seed", "many"])
    assert e.value.code == 2
    assert "argument --seed: invalid int: 'many'" in _last(capsys.readouterr().err)


def test_ctrl_c_exits_130_in_one_line(cli, monkeypatch, tmp_path: Path) -> None:
    def interrupted(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(cmd_validate, "run", interrupted)
    rc, _, err = cli("validate", tmp_path)
    assert rc == 130 and err == "exsur: interrupted\n"


def test_an_os_error_a_path_does_not_explain_is_not_hidden(monkeypatch, tmp_path: Path) -> None:
    def broken(args: argparse.Namespace) -> int:
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(cmd_validate, "run", broken)
    with pytest.raises(OSError, match="Input/output error"):
        main(["validate", str(tmp_path)])


# ---- --max-seconds (knobs.positive_seconds) -------------------------------------------------


def test_max_seconds_parses_a_number_and_refuses_a_word(data_dir: Path, capsys) -> None:
    from excavator_surrogate.cli.knobs import positive_seconds

    assert positive_seconds("--max-seconds")("7.5") == pytest.approx(7.5)
    with pytest.raises(SystemExit) as e:
        main(["train", str(data_dir / "ds3"), "--dry-run", "--max-seconds", "soon"])
    assert e.value.code == 2
    assert "argument --max-seconds: invalid value: 'soon' (seconds, or none for no budget)" in (
        _last(capsys.readouterr().err)
    )


def test_max_seconds_none_means_no_budget_as_the_help_says(data_dir: Path, capsys) -> None:
    """``--max-seconds none`` (offered by the help) was refused as an invalid float, and the
    error for ``0`` said to leave the option out, which keeps the preset's budget."""
    from excavator_surrogate.cli.knobs import positive_seconds

    for text in ("none", "None", "NONE"):
        assert positive_seconds("--max-seconds")(text) == 0.0  # the config's "no cap"
    argv = ["train", data_dir / "ds3", "--preset", data_dir / "tiny.toml", "--dry-run"]
    assert main([str(a) for a in [*argv, "--max-seconds", "none"]]) == 0
    assert "no wall-time cap" in capsys.readouterr().out
    with pytest.raises(ConfigError, match=r"> 0 \[s\], or none for no time budget"):
        positive_seconds("--max-seconds")("0")


# ---- validate -------------------------------------------------------------------------------


def test_validate_an_episode_file(cli, tmp_path: Path) -> None:
    ep = synthetic_episode(synthetic_spec(3), n_step=50, seed=1, name="ep")
    path = write_episode(tmp_path / "ep.parquet", ep)
    rc, out, err = cli("validate", path)
    assert rc == 0, err
    assert out == (
        f"{path}: ok, joints ['swing', 'boom', 'arm'] at 20 Hz, 50 samples, source {ep.source}\n"
    )


def test_validate_names_an_angle_far_outside_the_limits(cli, tmp_path: Path) -> None:
    ep = synthetic_episode(synthetic_spec(3), n_step=50, seed=1, name="ep")
    theta = ep.theta.copy()
    theta[10:13, 1] = 3.0  # boom limits [-1.2, 1.2] + 50 % of the range: 2.4
    path = write_episode(tmp_path / "ep.parquet", dataclasses.replace(ep, theta=theta))
    rc, out, err = cli("validate", path)
    assert rc != 0 and out == ""
    line = _last(err)
    assert line.startswith(f"exsur: error: {path}")
    assert "joint 'boom': angle 3 rad is outside the limits [-1.2, 1.2] rad" in line
    assert "in 3 sample(s)" in line and "theta_boom" in line and "outliers" in line


# ---- import: the split options --------------------------------------------------------------


def _split_args(**kw: object) -> argparse.Namespace:
    base = dict(split_file=None, train=None, val=None, test=None, split_by=None)
    return argparse.Namespace(**{**base, "fractions": None, "seed": None, **kw})


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (None, "--split-file not found; give a TOML file with train = [...]"),
        (b"train = [\n", "invalid TOML ("),
        (b"\xff\xfe train", "--split-file is not a TOML text file (not UTF-8"),
        (b"train = ['a']\nvalidation = ['b']\n", "unknown key(s) ['validation']; use train, val"),
        (b"val = 'b.csv'\n", "'val' must be a list of file names"),
    ],
)
def test_a_split_file_error_names_the_file(
    tmp_path: Path, text: bytes | None, message: str
) -> None:
    from excavator_surrogate.cli.cmd_import import _split_options
    from excavator_surrogate.ingest.options import SplitOptions

    f = tmp_path / "split.toml"
    if text is not None:
        f.write_bytes(text)
    with pytest.raises(ConfigError) as e:
        _split_options(_split_args(split_file=f), SplitOptions())
    assert str(e.value).startswith(f"{f}: ") and message in str(e.value)


def test_a_split_file_and_fractions_are_read(tmp_path: Path) -> None:
    from excavator_surrogate.cli.cmd_import import _split_options
    from excavator_surrogate.ingest.options import SplitOptions

    f = tmp_path / "split.toml"
    f.write_text("train = ['a.csv']\ntest = ['c.csv']\n")
    s = _split_options(_split_args(split_file=f), SplitOptions())
    assert (s.by, s.train, s.val, s.test) == ("file", ("a.csv",), (), ("c.csv",))
    s = _split_options(_split_args(fractions="0.6,0.2,0.2", seed=3), SplitOptions())
    assert s.fractions == pytest.approx((0.6, 0.2, 0.2)) and s.seed == 3


@pytest.mark.parametrize(
    ("fractions", "message"),
    [
        ("0.7;0.15;0.15", "--fractions '0.7;0.15;0.15': give three numbers, e.g. 0.7,0.15,0.15"),
        ("0.7,0.3", "--fractions '0.7,0.3': give three numbers (train,val,test)"),
    ],
)
def test_fractions_that_are_not_three_numbers(fractions: str, message: str) -> None:
    from excavator_surrogate.cli.cmd_import import _split_options
    from excavator_surrogate.ingest.options import SplitOptions

    with pytest.raises(ConfigError) as e:
        _split_options(_split_args(fractions=fractions), SplitOptions())
    assert str(e.value) == message


# ---- calibrate ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Untrained 2-joint checkpoints (one network, a 2-member ensemble) and three datasets:
    whole, without val, without train."""
    from tests.helpers.surrogates import make_surrogate

    from excavator_surrogate.surrogate.checkpoint import save_checkpoint
    from excavator_surrogate.surrogate.ensemble import merge

    root = tmp_path_factory.mktemp("calibrate")
    spec = synthetic_spec(2)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=1, n_step=80, noise=0.001)
    whole = write_dataset(root / "whole", items)
    no_val = write_dataset(root / "no_val", [(e, s) for e, s in items if s != "val"])
    no_train = write_dataset(root / "no_train", [(e, s) for e, s in items if s != "train"])
    ds = load_dataset(whole)
    surs = [
        make_surrogate(spec, ds.train, mode="stateful", window=5, hidden=8, seed=s) for s in (0, 1)
    ]
    return {
        "whole": whole,
        "no_val": no_val,
        "no_train": no_train,
        "one": save_checkpoint(root / "one.pt", surs[0]),
        "ens": save_checkpoint(root / "ens.pt", merge(surs)),
    }


def test_calibrate_refuses_a_negative_max_steps(cli, small) -> None:
    rc, _, err = cli("calibrate", small["one"], small["whole"], "--max-steps", "-3")
    assert rc == 2 and _last(err) == "exsur: error: --max-steps must be >= 0, got -3"


def test_calibrate_needs_training_episodes(cli, small) -> None:
    rc, _, err = cli("calibrate", small["one"], small["no_train"])
    assert rc == 2
    line = _last(err)
    assert (
        line.startswith(f"exsur: error: {small['no_train']}") and "has no training episodes" in line
    )
    assert "give the training dataset" in line


def test_calibrate_a_single_network_records_the_coverage_only(cli, small) -> None:
    rc, out, err = cli("calibrate", small["one"], small["whole"], "--max-steps", "40")
    assert rc == 0, err
    assert out.strip().endswith("(single network: no uncertainty bands)")
    assert "coverage of" in out and "training samples" in out


@pytest.mark.parametrize("train_runs", ["0", "32"])
def test_calibrate_an_ensemble_on_training_runs_without_a_val_split(
    cli, small, tmp_path: Path, train_runs: str
) -> None:
    """Without a validation split the bands are fitted on the training runs, and the record
    says so: with ``--train-runs 0`` it had stored them as 2 validation runs (rule "val"),
    which ``exsur info`` then reported as held out."""
    import shutil

    from excavator_surrogate.evaluate.card import _calibrated_from
    from excavator_surrogate.surrogate.checkpoint import read_checkpoint

    ckpt = Path(shutil.copy(small["ens"], tmp_path / "ens.pt"))
    rc, out, err = cli(
        "calibrate", ckpt, small["no_val"], "--train-runs", train_runs, "--max-steps", "40"
    )
    assert rc == 0, err
    assert "bands calibrated on" in out and "2 training runs (no val split: in-sample)" in out
    unc = read_checkpoint(ckpt)["metrics"]["uncertainty"]
    assert (unc["rule"], unc["n_run"], unc["n_train_run"]) == ("train", 0, 2)
    assert _calibrated_from(unc).endswith("of 2 training runs)")


def test_calibrate_help_describes_the_rule_it_runs(capsys) -> None:
    """The help said the scales came from the training runs, "raised where the validation
    runs significantly need more"; the code takes one quantile of both, validation weighing
    n_val / (n_val + PRIOR_RUNS) (bands.RULE), which can sit below what validation needs."""
    from excavator_surrogate.cli import cmd_calibrate
    from excavator_surrogate.surrogate import bands

    assert (cmd_calibrate.PRIOR_RUNS, cmd_calibrate.TRAIN_RUNS) == (
        bands.PRIOR_RUNS,
        bands.TRAIN_RUNS,
    )
    from excavator_surrogate.cli import main

    with pytest.raises(SystemExit) as done:
        main(["calibrate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert done.value.code == 0 and "raised where" not in text
    assert f"weighing n_val / (n_val + {bands.PRIOR_RUNS:g})" in text
    assert "level-quantile of |error| / spread" in text


def test_calibrate_replaces_a_malformed_calibration(cli, small, tmp_path: Path) -> None:
    """A malformed stored calibration had stopped ``exsur calibrate`` with that record's own
    advice ("malformed uncertainty calibration (sizes); calibrate again"): the free runs it
    fits on read it for bands they do not need.  Now it is replaced by the one a clean
    checkpoint gets."""
    import shutil

    import torch

    from excavator_surrogate.surrogate.checkpoint import read_checkpoint

    ckpt = Path(shutil.copy(small["ens"], tmp_path / "ens.pt"))
    args = ("calibrate", ckpt, small["whole"], "--max-steps", "40", "--train-runs", "1")
    assert cli(*args)[0] == 0
    good = read_checkpoint(ckpt)["metrics"]["uncertainty"]
    d = torch.load(ckpt, weights_only=True)
    d["metrics"]["uncertainty"]["theta_horizon"] = good["theta_horizon"][:1]
    torch.save(d, ckpt)
    rc, out, err = cli(*args)
    assert rc == 0, err
    assert "bands calibrated on" in out
    assert read_checkpoint(ckpt)["metrics"]["uncertainty"] == good


def test_calibrate_records_the_dataset_and_options_it_calibrated_on(
    cli, small, tmp_path: Path
) -> None:
    """The bands and the coverage record did not say which dataset they came from, nor
    ``--max-steps`` (which changes the bands): ``metrics["calibrated_on"]`` records both; a
    calibration without that record (training's own) leaves none behind."""
    import shutil

    from excavator_surrogate.surrogate.bands import calibrate_checkpoint
    from excavator_surrogate.surrogate.checkpoint import read_checkpoint

    ckpt = Path(shutil.copy(small["ens"], tmp_path / "ens.pt"))
    rc, _, err = cli("calibrate", ckpt, small["whole"], "--max-steps", "40", "--train-runs", "1")
    assert rc == 0, err
    assert read_checkpoint(ckpt)["metrics"]["calibrated_on"] == {
        "dataset": str(Path(small["whole"]).resolve()),
        "design": "shared",
        "max_steps": 40,
        "train_runs": 1,
    }
    ds = load_dataset(small["whole"])
    calibrate_checkpoint(ckpt, ds.val, ds.train, max_steps=40)
    assert "calibrated_on" not in read_checkpoint(ckpt)["metrics"]


# ---- info -----------------------------------------------------------------------------------


def test_info_refuses_csv_options_for_a_dataset(cli, data_dir: Path) -> None:
    rc, out, err = cli("info", data_dir / "ds3", "--set", "csv.delimiter=';'")
    assert rc == 2 and out == ""
    assert _last(err) == (
        f"exsur: error: {data_dir / 'ds3'}: --set csv.* reads a raw CSV log or dSPACE export, "
        "not this; leave it out"
    )


def test_info_lists_a_raw_parquet_logs_metadata(cli, tmp_path: Path) -> None:
    table = pa.table({"t": np.arange(5.0) * 0.1, "boom": np.linspace(0.0, 1.0, 5)})
    long = "x" * 80
    table = table.replace_schema_metadata({"machine": "SY750H", "notes": long})
    pq.write_table(table, tmp_path / "log.parquet")
    rc, out, err = cli("info", tmp_path / "log.parquet")
    assert rc == 0, err
    assert "Metadata (what `[[inputs]] from_metadata` reads):" in out
    assert "- `machine` = `'SY750H'`" in out
    assert f"- `notes` = `'{'x' * 57}...'`" in out and long not in out


def test_log_markdown_shows_the_start_and_span() -> None:
    from excavator_surrogate.cli.cmd_info import _log_markdown
    from excavator_surrogate.ingest.summary import ChannelSummary, LogSummary

    s = LogSummary(
        Path("run.mf4"),
        "mdf",
        "MDF 4.10",
        [ChannelSummary("boom", group="CG1", unit="deg", n_sample=10, rate_hz=100.0, lo=0, hi=1)],
        start="2024-05-01T10:00:00+00:00",
        duration_s=12.5,
    )
    head = _log_markdown(s).splitlines()
    assert head[0] == "# run.mf4: MDF 4.10"
    assert head[2] == "1 channel(s); starts 2024-05-01T10:00:00+00:00; 12.5 s long"


# ---- train ----------------------------------------------------------------------------------


def test_train_ddp_without_torchrun_is_one_line_and_writes_nothing(
    cli, data_dir: Path, tmp_path: Path, monkeypatch
) -> None:
    for k in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(k, raising=False)
    out = tmp_path / "m"
    rc, _, err = cli(
        "train", data_dir / "ds3", "--out", out, "--preset", data_dir / "tiny.toml", "--ddp"
    )
    assert rc == 2
    assert _last(err).startswith("exsur: error: --ddp needs a torchrun launch (")
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_learning_curves_that_cannot_be_drawn_are_a_warning(tmp_path: Path, caplog) -> None:
    from excavator_surrogate.cli.cmd_train import _learning_curves

    with caplog.at_level(logging.WARNING, logger="excavator_surrogate"):
        _learning_curves(tmp_path)  # no log.csv: nothing to draw
    assert "learning curves not drawn:" in caplog.text and "no epoch log" in caplog.text
    assert not (tmp_path / "learning_curve.png").exists()


def test_every_subcommands_help_reads_as_written() -> None:
    """argparse %-formats only arguments' help, not descriptions: a ``%%`` there prints as is."""
    from excavator_surrogate.cli import build_parser

    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert len(subs.choices) >= 10
    for name, sub in subs.choices.items():
        text = sub.format_help()
        assert "%%" not in text and "%(" not in text, name


# ---- names that are not UTF-8 -------------------------------------------------------------


def test_a_name_that_is_not_utf8_is_one_line(tmp_path: Path, capsys) -> None:
    """A path holding bytes that are not UTF-8 (a Latin-1 file name) crashed simulate, train
    and import with a UnicodeEncodeError traceback (pyarrow and TensorBoard write UTF-8
    names): one line naming it, before any work, and nothing is written."""
    bad = str(tmp_path / os.fsdecode(b"bad\xffname"))
    for argv in (["simulate", "--preset", "tiny", "--out", bad], ["validate", bad]):
        assert main(argv) == 2
        assert _last(capsys.readouterr().err) == (
            f"exsur: error: {tmp_path}/bad\\xffname: the name is not valid UTF-8 (e.g. a "
            "Latin-1 file name); rename it"
        )
    assert list(tmp_path.iterdir()) == []


def test_a_name_in_a_listed_folder_that_is_not_utf8_is_one_line(cli, monkeypatch) -> None:
    """A name the command finds itself (a log in a folder it imports) fails where a library
    encodes it: the same one line, not a traceback; other encoding errors are not hidden."""

    def encode(name: str):
        def run(args: argparse.Namespace) -> int:
            name.encode("utf-8")  # as pyarrow's encode_file_path does
            return 0

        return run

    monkeypatch.setattr(cmd_validate, "run", encode(os.fsdecode(b"logs/run\xe9.csv")))
    rc, _, err = cli("validate", "x")
    assert rc == 2 and err == (
        "exsur: error: logs/run\\xe9.csv: the name is not valid UTF-8 (e.g. a Latin-1 file "
        "name); rename it\n"
    )
    monkeypatch.setattr(cmd_validate, "run", lambda args: "θ".encode("ascii"))
    with pytest.raises(UnicodeEncodeError):
        main(["validate", "x"])


def test_calibrate_rewrites_the_linked_file_keeps_its_mode_and_waits_for_a_writer(
    cli, small, tmp_path: Path, monkeypatch
) -> None:
    """calibrate replaced a linked checkpoint with a copy, made a private (0600) one world
    readable, rewrote a read-only one and ignored a running train's writer lock."""
    import shutil

    from excavator_surrogate.surrogate.checkpoint import read_checkpoint

    shared = tmp_path / "shared"
    shared.mkdir()
    target = Path(shutil.copy(small["one"], shared / "best.pt"))
    target.chmod(0o600)
    link = tmp_path / "mylink.pt"
    link.symlink_to(target)
    argv = (small["whole"], "--max-steps", "40")
    rc, _, err = cli("calibrate", link, *argv)
    assert rc == 0, err
    assert link.is_symlink() and "coverage" in read_checkpoint(target)["metrics"]
    assert target.stat().st_mode & 0o777 == 0o600
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, m: Path(p) != target and real(p, m))
    rc, _, err = cli("calibrate", target, *argv)
    assert rc == 2 and _last(err) == (
        f"exsur: error: {target}: not writable (calibrate rewrites the checkpoint in place); "
        "copy it or fix its permissions"
    )
    monkeypatch.undo()
    with lock_held_elsewhere(shared) as proc:  # what 'exsur train --out shared' holds
        rc, _, err = cli("calibrate", link, *argv)
    assert rc == 2 and _last(err) == (
        f"exsur: error: {shared}: another exsur process (pid {proc.pid}) is writing this "
        "folder; wait for it to finish or give another folder"
    )
