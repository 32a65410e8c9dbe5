"""``exsur clean`` command line and the fusion figure."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.clean import clean_episode
from excavator_surrogate.cli import main
from excavator_surrogate.data import read_manifest
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.plotting.fusion import plot_fusion

PNG = b"\x89PNG"


def test_cli_clean_method_and_plot(noisy_dataset, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    assert (
        main(["clean", str(noisy_dataset), "--out", str(out), "--method", "paper", "--plot"]) == 0
    )
    text = capsys.readouterr().out
    assert "method paper" in text and "bucket" in text
    assert read_manifest(out)["config"]["clean"]["method"] == "paper"
    figs = sorted((out / "figures").glob("*.png"))
    assert len(figs) == 4 and all(f.read_bytes()[:4] == PNG for f in figs)


def test_cli_preset_table(noisy_dataset, tmp_path, capsys) -> None:
    preset = tmp_path / "p.toml"
    preset.write_text('[clean]\nmethod = "gyro3"\ntau_cons = 0.05\n')
    out = tmp_path / "out"
    assert main(["clean", str(noisy_dataset), "--out", str(out), "--preset", str(preset)]) == 0
    cfg = read_manifest(out)["config"]["clean"]
    assert cfg["method"] == "gyro3" and cfg["tau_cons"] == 0.05
    # --method overrides the preset
    assert (
        main(
            [
                "clean",
                str(noisy_dataset),
                "--out",
                str(out),
                "--preset",
                str(preset),
                "--method",
                "rts",
            ]
        )
        == 0
    )
    assert read_manifest(out)["config"]["clean"]["method"] == "rts"


@pytest.mark.parametrize(
    ("preset_text", "needle"),
    [
        ("[clean]\ntau = 1.0\n", "unknown key(s) ['tau']"),
        ('[clean]\ncons_window = "x"\n', "cons_window"),
    ],
)
def test_cli_user_errors_are_one_line(noisy_dataset, tmp_path, capsys, preset_text, needle) -> None:
    preset = tmp_path / "bad.toml"
    preset.write_text(preset_text)
    rc = main(["clean", str(noisy_dataset), "--out", str(tmp_path / "o"), "--preset", str(preset)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith("exsur: error:") and needle in err and "\n" not in err
    assert not (tmp_path / "o").exists()
    rc = main(["clean", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "nowhere" in err and "\n" not in err


def test_plot_fusion(noisy_episode, tmp_path) -> None:
    cleaned = clean_episode(noisy_episode)
    p = plot_fusion(
        noisy_episode, cleaned, joint="bucket", path=tmp_path / "f.png", t_range=(5.0, 40.0)
    )
    assert p.read_bytes()[:4] == PNG
    p2 = plot_fusion(
        noisy_episode.replace(theta_true=None), cleaned, joint=0, path=tmp_path / "g.png"
    )
    assert p2.exists()
    with pytest.raises(ConfigError, match="unknown joint"):
        plot_fusion(noisy_episode, cleaned, joint="stick", path=tmp_path / "h.png")
    with pytest.raises(ConfigError, match="t_range"):
        plot_fusion(noisy_episode, cleaned, joint=1, path=tmp_path / "h.png", t_range=(1e6, 2e6))
    assert np.isfinite(cleaned.theta).all()


@pytest.mark.parametrize(
    ("scale", "needle"),
    [
        (180 / np.pi, "x the angle's rate of change (looks like deg/s)"),
        (-1.0, "the gyro has the opposite sign of the angle's rate of change"),
    ],
)
def test_a_gyro_off_by_a_unit_or_sign_is_refused(noisy_dataset, tmp_path, capsys, scale, needle):
    """A gyro in deg/s (or of the wrong sign) under rad/s columns was fused into angles tens
    of radians off the data, and exsur clean said ok."""
    from excavator_surrogate.data import load_dataset, write_dataset

    ds = load_dataset(noisy_dataset)
    items = [(ep, s) for s in ("train", "val", "test") for ep in ds.split(s)]
    items[2] = (items[2][0].replace(omega=items[2][0].omega * scale), "val")
    bad = write_dataset(tmp_path / "bad", items)
    rc = main(["clean", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1].startswith("exsur: error: ") and "error" not in "".join(err[:-1])
    assert f"{bad / 'episodes' / 'ep2.parquet'}, column 'omega_swing': joint 'swing': " in err[-1]
    assert needle in err[-1] and "re-import the log" in err[-1]
    assert not (tmp_path / "o").exists()
    with pytest.raises(DataError, match=r"^ep2, column 'omega_swing'"):
        clean_episode(items[2][0])


def test_a_noisy_gyro_is_warned_about(noisy_episode, tmp_path, caplog) -> None:
    """Most samples distrusted: the stage says so (the fused angles are then mostly the
    integrated gyro)."""
    import logging

    from excavator_surrogate.clean import clean_dataset
    from excavator_surrogate.data import write_dataset

    rng = np.random.default_rng(0)
    ep = noisy_episode.replace(omega=noisy_episode.omega + 0.3 * rng.standard_normal((1200, 4)))
    src = write_dataset(tmp_path / "raw", [(ep, "train")])
    with caplog.at_level(logging.WARNING):
        clean_dataset(src, tmp_path / "c")
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "the filter distrusted swing's angle in 74%, boom's" in warned[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        clean_dataset(write_dataset(tmp_path / "ok", [(noisy_episode, "train")]), tmp_path / "c2")
    assert not [r for r in caplog.records if r.levelno == logging.WARNING]
