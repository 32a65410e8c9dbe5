"""Every ``config.toml`` exsur records loads back as a ``--preset`` to the same configs.

The project's rule: an output folder records its config, and a user reproduces the run from
it.  The strict ``[train]`` check refuses a knob the table's mode does not read, even at its
default (a hand-written preset's slip), so the records must leave those knobs out
(:func:`excavator_surrogate.config.to_dict` drops ``TrainConfig.unread_fields()``).
"""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest

from excavator_surrogate.config import dumps_toml, preset_names, to_dict
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.pipeline import resolve_run
from excavator_surrogate.stages import RECORD_TABLES, build_configs, load_preset
from excavator_surrogate.training import TrainConfig
from excavator_surrogate.training.config import MODE_FIELDS

CLI = Callable[..., tuple[int, str, str]]


def _reloaded(record: Path) -> dict[str, object]:
    """The configs of every table of ``record`` loaded as a preset, as the commands load it."""
    preset = load_preset(record)
    sections = [k for k, v in preset.items() if isinstance(v, dict) and k not in RECORD_TABLES]
    return build_configs(preset, sections=sections, where=str(record))


def _assert_round_trip(record: Path) -> dict[str, object]:
    """``record`` loads as a preset, and each of its tables builds the config it records."""
    raw = tomllib.loads(record.read_text())
    cfgs = _reloaded(record)
    assert cfgs, f"{record}: no table"
    for section, cfg in cfgs.items():
        assert to_dict(cfg) == raw[section], f"{record} [{section}] loads to other values"
    return cfgs


@pytest.mark.slow
def test_every_recorded_config_loads_back_as_its_preset(tmp_path: Path, cli: CLI) -> None:
    """simulate, clean, train, run and a sweep's trial: each folder's ``config.toml`` is a
    preset that builds the configs the command ran with (train's and run's failed with
    "batch_size is read only by mode = "windowed"")."""
    fast = ["--epochs", "1", "--set", "train.tensorboard=false", "-q"]
    sim, cl, model, run, sweep = (tmp_path / n for n in ("sim", "cl", "model", "run", "sweep"))

    def ok(*argv: str | Path) -> None:
        rc, _, err = cli(*argv)
        assert rc == 0, err

    ok("simulate", "--preset", "tiny", "--out", sim, "-q")
    ok("clean", sim, "--preset", "tiny", "--out", cl, "-q")
    ok("train", sim, "--preset", "tiny", "--out", model, *fast)
    ok("run", "--preset", "tiny", "--out", run, *fast)
    ok("sweep", sim, "--preset", "tiny", "--out", sweep, "--trials", "2", *fast)

    tiny = load_preset("tiny")
    want_sim = build_configs(tiny, sections=["simulate"])["simulate"]
    assert _assert_round_trip(sim / "config.toml")["simulate"] == want_sim
    assert "clean" in _assert_round_trip(cl / "config.toml")
    over = {"train": {"epochs": 1, "tensorboard": False}}
    want_train = build_configs(tiny, sections=["train"], overrides=over)["train"]
    assert _assert_round_trip(model / "config.toml")["train"] == want_train
    want = resolve_run(preset="tiny", epochs=1, sets={"train": {"tensorboard": False}})
    got = _assert_round_trip(run / "config.toml")
    assert set(got) == {"run", "simulate", "train", "evaluate"}
    for section, cfg in got.items():
        assert cfg == want.configs[section], section
    assert resolve_run(preset=str(run / "config.toml")).configs == want.configs
    assert set(_assert_round_trip(sweep / "config.toml")) == {"train", "sweep"}
    trials = sorted(sweep.glob("trials/*/config.toml"))
    assert trials
    for record in trials:
        _assert_round_trip(record)
    for folder in [
        model,
        run,
        run / "model",
        run / "model_gru",
        sweep,
        *(t.parent for t in trials),
    ]:
        ok("config", "show", folder / "config.toml")

    # the command itself takes its own record back, and records the same again
    again = tmp_path / "again"
    ok("train", sim, "--preset", model / "config.toml", "--out", again, "-q")
    assert (again / "config.toml").read_text() == (model / "config.toml").read_text()


@pytest.mark.parametrize("mode", sorted(MODE_FIELDS))
@pytest.mark.parametrize("preset", preset_names())
def test_run_record_of_every_preset_and_mode_loads_back(
    preset: str, mode: str, tmp_path: Path
) -> None:
    """The ``config.toml`` ``exsur run`` records (:meth:`RunRequest.record`, also printed by
    ``run --dry-run``) of every shipped preset, in either mode, resolves to the same configs."""
    req = resolve_run(preset=preset, sets={"train": {"mode": mode}})
    record = req.record(train=req.configs["train"], evaluate=req.configs["evaluate"])
    unread = set(MODE_FIELDS[next(m for m in MODE_FIELDS if m != mode)])
    assert not unread & set(record["train"]), "the record holds knobs its mode does not read"
    path = tmp_path / "config.toml"
    path.write_text(dumps_toml(record))
    again = resolve_run(preset=str(path))
    # a recipe run records its plan as it ran, to be trained as is (auto_train off), and the
    # reference it scores against is run.reference, whatever [evaluate] said
    run = dataclasses.replace(req.configs["run"], auto_train=False)
    ev = dataclasses.replace(req.configs["evaluate"], reference=run.reference)
    assert again.configs == {**req.configs, "run": run, "evaluate": ev}
    assert again.record(train=again.configs["train"], evaluate=again.configs["evaluate"]) == record


def test_a_recipe_runs_record_trains_its_plan_again(tmp_path: Path) -> None:
    """``[run] auto_train``: the record holds the recipe's plan for the data; read back with
    the recipe on, its per-network time cap was planned as the whole budget (76.5 s became
    10.8 s a network)."""
    from excavator_surrogate.data import load_dataset, write_dataset
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split

    items = synthetic_split(synthetic_spec(2), n_train=3, n_val=1, n_test=1, n_step=200)
    data = write_dataset(tmp_path / "data", items)
    req = resolve_run(preset="real", data=str(data))
    assert req.configs["run"].auto_train
    planned, _ = req.train_recipe(load_dataset(data), cpus=2)
    path = tmp_path / "config.toml"
    path.write_text(dumps_toml(req.record(train=planned, evaluate=req.configs["evaluate"])))
    again = resolve_run(preset=str(path), data=str(data))
    assert not again.configs["run"].auto_train
    assert again.configs["train"] == planned


@pytest.mark.parametrize("mode", sorted(MODE_FIELDS))
def test_to_dict_leaves_out_the_knobs_the_mode_does_not_read(mode: str) -> None:
    cfg = TrainConfig(mode=mode)  # type: ignore[arg-type]
    table = to_dict(cfg)
    assert cfg.unread_fields() and not set(cfg.unread_fields()) & set(table)
    assert TrainConfig.from_preset({"train": table}) == cfg


def test_a_hand_written_stray_knob_is_still_refused(tmp_path: Path) -> None:
    """Leaving the knobs out of the records keeps the strict check: a hand-written
    ``batch_size`` in a stateful table is refused even at its default."""
    path = tmp_path / "mine.toml"
    path.write_text('[train]\nmode = "stateful"\nbatch_size = 256\n')
    with pytest.raises(ConfigError, match='batch_size is read only by mode = "windowed"'):
        build_configs(load_preset(path), sections=["train"])
    path.write_text('[train]\nmode = "windowed"\nseq_len = 150\n')
    with pytest.raises(ConfigError, match='seq_len is read only by mode = "stateful"'):
        build_configs(load_preset(path), sections=["train"])


def _tiny_model(tmp_path: Path) -> tuple[Path, Path]:
    """A tiny dataset on disk and a one-epoch model trained on it: ``(data, model folder)``."""
    from excavator_surrogate.data import load_dataset
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, write_synthetic_dataset
    from excavator_surrogate.training import train
    from tests.helpers.training import tiny_train_config

    data = write_synthetic_dataset(
        tmp_path / "data", synthetic_spec(2), n_train=2, n_val=1, n_test=1, n_step=120
    )
    model = tmp_path / "model"
    train(tiny_train_config(epochs=1), load_dataset(data), out=model, show_progress=False)
    return data, model


def test_an_evaluation_records_its_config_beside_a_trainings(tmp_path: Path, cli: CLI) -> None:
    """``exsur evaluate`` wrote no ``config.toml``: its ``[evaluate]`` options (``--no-arx``,
    ``--max-steps`` ...) and its inputs (the checkpoint, the dataset, ``--compare``) were lost.
    Its record loads back as ``--preset``; written into a model folder, it keeps the
    training's ``[train]``."""
    from excavator_surrogate.evaluate.cbe import EvaluateConfig

    data, model = _tiny_model(tmp_path)
    best, ev = model / "best.pt", tmp_path / "ev"
    quick = ["--no-structured", "--set", "evaluate.figure=false", "-q"]
    rc, _, err = cli(
        "evaluate",
        best,
        data,
        "--out",
        ev,
        "--no-arx",
        "--max-steps",
        "80",
        "--compare",
        f"G={best}",
        "--set",
        "evaluate.horizons=[0.5]",
        *quick,
    )
    assert rc == 0, err
    want = EvaluateConfig(arx=False, structured=False, max_steps=80, figure=False, horizons=(0.5,))
    assert _assert_round_trip(ev / "config.toml") == {"evaluate": want}
    assert tomllib.loads((ev / "config.toml").read_text())["command"] == {
        "name": "evaluate",
        "checkpoint": str(best.resolve()),
        "dataset": str(data.resolve()),
        "compare": {"G": str(best.resolve())},
        "device": "cpu",
    }
    trained = tomllib.loads((model / "config.toml").read_text())["train"]
    rc, _, err = cli("evaluate", best, data, "--out", model, *quick)
    assert rc == 0, err
    got = _assert_round_trip(model / "config.toml")
    assert set(got) == {"train", "evaluate"} and to_dict(got["train"]) == trained
    assert tomllib.loads((model / "config.toml").read_text())["command"]["checkpoint"] == "best.pt"
