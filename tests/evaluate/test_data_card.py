"""exsur info DATASET: a dataset's splits and what each covers, with the notes that matter."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.data import write_dataset
from excavator_surrogate.data.dataset import load_dataset
from excavator_surrogate.evaluate.data_card import MIN_SPAN, dataset_card, dataset_card_markdown
from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split
from excavator_surrogate.training.span import command_span


def _items(*, val_scale: float = 1.0, test_shift: float = 0.0):
    spec = synthetic_spec(3)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=1, n_step=200, noise=0.001)
    out = []
    for ep, split in items:
        if split == "val" and val_scale != 1.0:
            ep = ep.replace(u=ep.u * val_scale)  # validation commands a small part only
        if split == "test" and test_shift:
            theta = ep.theta.copy()
            theta[:, 1] = np.clip(theta[:, 1] * 0.2 + test_shift, -1.19, 1.19)
            ep = ep.replace(theta=theta, theta_true=None, omega_true=None)
        out.append((ep, split))
    return out


@pytest.fixture(scope="module")
def plain_dir(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("ds") / "data", _items())


def test_the_card_counts_every_split_and_measures_each_joint(plain_dir):
    ds = load_dataset(plain_dir)
    card = dataset_card(plain_dir)
    assert list(card["splits"]) == ["train", "val", "test"]
    tr = card["splits"]["train"]
    assert tr["episodes"] == 2 and tr["samples"] == ds.n_samples("train")
    assert tr["duration_s"] == pytest.approx(ds.n_samples("train") * ds.spec.dt)
    assert tr["truth"] and not tr["cleaned"]
    # a limited joint: its range and speed over the split, as numpy gives them
    boom = card["joints"][1]["splits"]["train"]
    theta = np.concatenate([e.theta[:, 1] for e in ds.train])
    omega = np.concatenate([e.omega[:, 1] for e in ds.train])
    assert boom["theta_min"] == theta.min() and boom["theta_max"] == theta.max()
    assert boom["omega_p99"] == pytest.approx(np.percentile(np.abs(omega), 99))
    # the periodic joint: the angle travelled, unwrapped
    swing = card["joints"][0]["splits"]["train"]
    travel = sum(np.abs(np.diff(np.unwrap(e.theta[:, 0]))).sum() for e in ds.train)
    assert swing["theta_min"] is None and swing["travel"] == pytest.approx(travel)
    assert card["val_span"] == dict(
        zip(ds.spec.names, command_span(ds.train, ds.val, ds.spec), strict=True)
    )
    text = dataset_card_markdown(card)
    assert "| train | 2 | 400 | 20.0 s |" in text
    deg = math.degrees
    assert f"| boom | train | {deg(theta.min()):.1f} … {deg(theta.max()):.1f} ° |" in text
    assert "° travelled" in text and "Validation reaches" in text


def test_thin_validation_and_a_test_off_the_training_positions_are_noted(tmp_path):
    root = write_dataset(tmp_path / "d", _items(val_scale=0.2, test_shift=1.1))
    card = dataset_card(root)
    low = [n for n, s in card["val_span"].items() if s < MIN_SPAN]
    assert low  # the scaled-down validation commands reach a small share of the range
    notes = " ".join(card["warnings"])
    assert "validation commands" in notes and all(f"{n} " in notes for n in low)
    assert "the test moves beyond the training's positions on boom" in notes
    assert "beyond the training's positions on arm" not in notes  # unchanged joint: inside
    assert "**Note:** validation commands" in dataset_card_markdown(card)


def test_missing_splits_are_noted(tmp_path):
    items = [(ep, s) for ep, s in _items() if s == "train"]
    card = dataset_card(write_dataset(tmp_path / "d", items))
    assert card["val_span"] is None and list(card["splits"]) == ["train"]
    notes = " ".join(card["warnings"])
    assert "no validation split" in notes and "no test split" in notes


def test_exsur_info_tells_a_dataset_from_a_checkpoint(plain_dir, tmp_path, capsys):
    assert main(["info", str(plain_dir)]) == 0
    assert capsys.readouterr().out.startswith(f"# {plain_dir}\n\nA dataset of **")
    assert main(["info", str(plain_dir), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got == json.loads(json.dumps(dataset_card(plain_dir)))
    # a folder that is neither: one line, naming what to give
    (tmp_path / "other").mkdir()
    assert main(["info", str(tmp_path / "other")]) == 2
    err = capsys.readouterr().err
    assert "a folder without manifest.json is not a dataset; give a checkpoint file" in err
    assert main(["info", str(tmp_path / "gone")]) == 2
    assert (
        "gone: not found; give a checkpoint file (.pt), an ONNX export (.onnx), a dataset folder, "
        "an episode file (.parquet) or a raw log" in (capsys.readouterr().err)
    )


def test_exsur_info_describes_one_episode_file(plain_dir, capsys):
    """An episode file gets the dataset card's joint table for itself alone (the same
    numbers as a dataset holding only it) and its record; a broken one is one line."""
    ds = load_dataset(plain_dir)
    ep = ds.test[0]
    path = plain_dir / next(e["file"] for e in ds.manifest["episodes"] if e["split"] == "test")
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"# {path}\n\nAn episode of **") and f"Episode `{ep.name}`" in text
    assert "| Joint | Episode | Position | Speed | Command |" in text
    boom = ep.theta[:, 1]
    deg = math.degrees
    assert f"| boom | {ep.name} | {deg(boom.min()):.1f} … {deg(boom.max()):.1f} ° |" in text
    assert main(["info", str(path), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["kind"] == "episode" and got["episode"]["name"] == ep.name
    assert (
        got["joints"][1]["splits"][ep.name]
        == dataset_card(plain_dir)["joints"][1]["splits"]["test"]
    )
    bad = path.with_name("bad.parquet")
    bad.write_bytes(b"PAR1 not parquet")
    assert main(["info", str(bad)]) == 2
    assert "bad.parquet: not a readable Parquet file" in capsys.readouterr().err
