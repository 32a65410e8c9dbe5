"""``exsur clean`` command line and the fusion figure."""

from __future__ import annotations

import numpy as np
import pytest

from excavator_surrogate.clean import clean_episode
from excavator_surrogate.cli import main
from excavator_surrogate.data import read_manifest
from excavator_surrogate.errors import ConfigError
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
