"""The library logs through ``logging`` (silent unless the application shows it); the CLI shows
``[exsur] ...`` lines on stderr and every subcommand takes ``-q`` and ``-v``."""

from __future__ import annotations

import argparse
import logging
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from excavator_surrogate.cli import build_parser, main
from excavator_surrogate.cli.common import leaf_parsers
from excavator_surrogate.data import load_dataset
from excavator_surrogate.io_utils import (
    LOGGER_NAME,
    init_worker_logging,
    progress,
    remove_logging,
    setup_logging,
    worker_log_config,
)
from excavator_surrogate.simulate import SimulateConfig, simulate_dataset
from excavator_surrogate.training import train
from tests.helpers.training import tiny_train_config

PKG = logging.getLogger(LOGGER_NAME)


@pytest.fixture(autouse=True)
def _restore_logging():
    """Every test leaves the package logger as it found it (no handler, no level)."""
    yield
    remove_logging()
    PKG.setLevel(logging.NOTSET)


def _simulate_and_train(out: Path) -> None:
    """A tiny simulate + train through the Python API (a few seconds)."""
    cfg = SimulateConfig.from_preset("tiny", steps_train=80, steps_val=80, steps_test=80)
    ds = load_dataset(simulate_dataset(cfg, out=out / "data"), splits=("train", "val"))
    train(tiny_train_config(epochs=1, window=4, burn_in=4), ds, out=out / "model")


def _ours(caplog) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name.split(".")[0] == LOGGER_NAME]


def test_a_python_run_at_warning_shows_no_info(tmp_path, capsys, caplog):
    caplog.set_level(logging.DEBUG)  # the root lets everything through: only our level filters
    PKG.setLevel(logging.WARNING)
    _simulate_and_train(tmp_path / "quiet")
    assert [r for r in _ours(caplog) if r.levelno < logging.WARNING] == []
    cap = capsys.readouterr()
    assert "[exsur]" not in cap.out + cap.err
    # the control: at INFO the same run logs its progress lines (and only to logging)
    PKG.setLevel(logging.INFO)
    _simulate_and_train(tmp_path / "chatty")
    infos = [r.getMessage() for r in _ours(caplog) if r.levelno == logging.INFO]
    assert any(m.startswith("simulate: wrote") for m in infos)
    assert any(m.startswith("epoch 0:") for m in infos)
    assert {r.name for r in _ours(caplog)} >= {  # module loggers
        "excavator_surrogate.simulate.generate",
        "excavator_surrogate.training.loop",
    }
    cap = capsys.readouterr()
    assert "[exsur]" not in cap.out + cap.err  # a library does not print: the app decides


def test_setup_logging_shows_exsur_lines_on_stderr(capsys):
    setup_logging(logging.INFO)
    setup_logging(logging.INFO)  # a second call replaces the handler: no doubled lines
    logging.getLogger(f"{LOGGER_NAME}.x").info("hello")
    logging.getLogger(f"{LOGGER_NAME}.x").debug("hidden")
    logging.getLogger(f"{LOGGER_NAME}.x").warning("careful")
    assert capsys.readouterr().err == "[exsur] hello\n[exsur] warning: careful\n"


def _commands() -> list[tuple[str, argparse.ArgumentParser]]:
    parser = build_parser()
    return [(leaf.prog, leaf) for leaf in leaf_parsers(parser)]


@pytest.mark.parametrize(("prog", "leaf"), _commands(), ids=[p for p, _ in _commands()])
def test_every_subcommand_takes_quiet_and_verbose(prog, leaf):
    assert prog.startswith("exsur ")
    for opt, dest in (("-q", "quiet"), ("--quiet", "quiet"), ("-v", "verbose")):
        assert leaf._option_string_actions[opt].dest == dest, (prog, opt)
    with pytest.raises(SystemExit):  # one or the other
        leaf.parse_args(["-q", "-v"])


def test_the_commands_cover_every_module():
    progs = {p for p, _ in _commands()}
    assert {"exsur simulate", "exsur validate", "exsur train", "exsur config show"} <= progs
    assert "exsur config" not in progs  # a group: its commands take the options


def test_quiet_simulate_and_validate_print_nothing(tmp_path, capsys):
    out = tmp_path / "ds"
    assert main(["simulate", "--preset", "tiny", "--out", str(out), "-q"]) == 0
    cap = capsys.readouterr()
    assert cap.err == "" and cap.out == ""  # the result is in --out
    # main() restored the logger: no level, no handler but the library's NullHandler
    assert PKG.level == logging.NOTSET
    assert all(isinstance(h, logging.NullHandler) for h in PKG.handlers)
    assert main(["validate", str(out), "-q"]) == 0
    cap = capsys.readouterr()
    assert cap.err == "" and cap.out == ""
    assert main(["config", "show", "tiny", "-q"]) == 0  # asked to show: it shows
    assert "[train]" in capsys.readouterr().out
    assert main(["validate", str(out)]) == 0
    assert capsys.readouterr().out.startswith(f"{out}: ok")  # the control
    # the control: without -q the same command tells what it does; -v adds debug lines
    assert main(["simulate", "--preset", "tiny", "--out", str(tmp_path / "b"), "-v"]) == 0
    err = capsys.readouterr().err
    assert "[exsur] simulate: wrote" in err and "[exsur] debug: exsur " in err
    assert main(["validate", str(out)]) == 0
    assert "debug" not in capsys.readouterr().err


def test_progress_bars_follow_the_logger_level(monkeypatch):
    monkeypatch.setenv("EXSUR_PROGRESS", "1")
    setup_logging(logging.WARNING)
    assert progress(range(3)).disable is True
    setup_logging(logging.INFO)
    assert progress(range(3)).disable is False
    assert progress(range(3), disable=True).disable is True


def test_a_worker_logs_at_the_parent_level_with_its_tag(capsys):
    init_worker_logging((logging.DEBUG, True), tag="seed1")
    logging.getLogger(f"{LOGGER_NAME}.x").debug("epoch 1")
    assert capsys.readouterr().err == "[seed1] debug: epoch 1\n"
    remove_logging()
    init_worker_logging((logging.WARNING, False))  # the parent shows nothing: neither do we
    assert PKG.level == logging.WARNING
    assert all(isinstance(h, logging.NullHandler) for h in PKG.handlers)


def _child_logs() -> None:
    log = logging.getLogger(f"{LOGGER_NAME}.child")
    log.info("child info")
    log.warning("child warning")


def test_a_spawned_worker_follows_the_parent_level(capfd):
    setup_logging(logging.WARNING)  # what `exsur ... -q` does
    assert worker_log_config() == (logging.WARNING, True)
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(
        1, mp_context=ctx, initializer=init_worker_logging, initargs=(worker_log_config(),)
    ) as pool:
        pool.submit(_child_logs).result()
    err = capfd.readouterr().err
    assert "[exsur] warning: child warning" in err and "child info" not in err
