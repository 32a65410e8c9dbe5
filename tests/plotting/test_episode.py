"""The episode figure (plotting.episode, ``exsur plot``): units of its rows per joint."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.data import Episode
from excavator_surrogate.plotting import episode as figure
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec

MIXED = MachineSpec(
    (
        JointSpec("swing", periodic=True),
        JointSpec("boom", kind="linear", unit="mm", u_unit="%", u_min=-100, u_max=100),
        JointSpec("bucket", kind="linear", unit="cm"),
    ),
    rate_hz=20.0,
)


def _episode(spec: MachineSpec) -> Episode:
    n = 40
    t = np.arange(n) * spec.dt
    theta = np.tile(np.linspace(0.5, 0.6, n)[:, None], (1, spec.n_joint))  # [rad] or [m]
    omega = np.full((n, spec.n_joint), 0.05)  # [rad/s] or [m/s]
    return Episode(spec=spec, time=t, u=np.zeros((n, spec.n_joint)), theta=theta, omega=omega)


def _drawn(spec: MachineSpec, monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """The figure plot_episode draws for an episode of ``spec`` (not written)."""
    seen = {}

    def capture(fig, out, dpi):
        seen["fig"] = fig
        return out

    monkeypatch.setattr(figure, "save_png", capture)
    figure.plot_episode(_episode(spec), out=tmp_path / "e.png")
    return np.array(seen["fig"].axes).reshape(3, spec.n_joint)


def test_a_stroke_is_drawn_and_labelled_in_its_unit(monkeypatch, tmp_path) -> None:
    """Strokes stored in m were drawn as they are and labelled rad on column 0 only."""
    axes = _drawn(MIXED, monkeypatch, tmp_path)
    labels = [[ax.get_ylabel() for ax in row] for row in axes]
    assert labels == [
        ["u [command]", "u [%]", "u [command]"],
        ["theta [rad]", "stroke [mm]", "stroke [cm]"],
        ["omega [rad/s]", "velocity [mm/s]", "velocity [cm/s]"],
    ]
    theta = [ax.lines[0].get_ydata() for ax in axes[1]]
    np.testing.assert_allclose([theta[0][0], theta[1][0], theta[2][0]], [0.5, 500.0, 50.0])
    omega = [ax.lines[0].get_ydata()[0] for ax in axes[2]]
    np.testing.assert_allclose(omega, [0.05, 50.0, 5.0])


def test_a_revolute_machine_is_drawn_as_before(monkeypatch, tmp_path) -> None:
    axes = _drawn(EXCAVATOR, monkeypatch, tmp_path)
    labels = [[ax.get_ylabel() for ax in row] for row in axes]
    assert labels == [[lab, "", "", ""] for lab in ("u [command]", "theta [rad]", "omega [rad/s]")]
    np.testing.assert_allclose(axes[1, 2].lines[0].get_ydata(), np.linspace(0.5, 0.6, 40))
    np.testing.assert_allclose(axes[2, 3].lines[0].get_ydata(), 0.05)
