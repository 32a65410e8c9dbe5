"""The cleaning stage's fusion figure (plotting.fusion)."""

from __future__ import annotations

import numpy as np

from excavator_surrogate.data import Episode
from excavator_surrogate.plotting import fusion
from excavator_surrogate.spec import excavator_spec


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_the_swing_truth_is_drawn_on_the_raw_angles_branch(monkeypatch, tmp_path):
    """A swing crossing +-pi: the raw angle is unwrapped for the figure, and the truth must
    be too (it was drawn wrapped, dropping 2 pi at each crossing under the raw curve)."""
    spec = excavator_spec(20.0)
    n = 400
    t = np.arange(n) * spec.dt
    true = np.zeros((n, 4))
    true[:, 0] = 2.8 + 0.05 * t  # crosses +pi at t = 6.8 s
    omega = np.zeros((n, 4))
    omega[:, 0] = 0.05
    raw = Episode(
        spec=spec,
        time=t,
        u=np.zeros((n, 4)),
        theta=_wrap(true + 1e-3),
        omega=omega,
        theta_true=_wrap(true),
        omega_true=omega,
        name="cross",
    )
    seen = {}

    def capture(time, theta_raw, omega_raw, theta_fused, **kw):
        seen.update(theta_raw=theta_raw, theta_true=kw["theta_true"])
        return kw["path"]

    monkeypatch.setattr(fusion, "plot_fusion_arrays", capture)
    fusion.plot_fusion(raw, raw, joint="swing", path=tmp_path / "f.png")
    np.testing.assert_allclose(seen["theta_raw"], true[:, 0] + 1e-3, atol=1e-9)
    np.testing.assert_allclose(seen["theta_true"], true[:, 0], atol=1e-9)
    fusion.plot_fusion(raw, raw, joint="swing", path=tmp_path / "f.png", t_range=(10.0, 15.0))
    np.testing.assert_allclose(seen["theta_raw"] - seen["theta_true"], 1e-3, atol=1e-9)


def _figure_of(monkeypatch, **kw):
    """The axes plot_fusion draws (the figure is closed, not kept)."""
    import matplotlib.pyplot as plt

    seen = {}
    close = plt.close

    def keep(fig):
        seen["ax"] = fig.axes[0]
        close(fig)

    monkeypatch.setattr(plt, "close", keep)
    fusion.plot_fusion(**kw)
    return seen["ax"]


def test_a_stroke_is_drawn_in_its_unit_and_an_angle_in_rad(monkeypatch, tmp_path):
    """A stroke stored in m was drawn as is and labelled 'boom angle [rad]'."""
    from excavator_surrogate.spec import JointSpec, MachineSpec

    spec = MachineSpec(
        (JointSpec("swing", periodic=True), JointSpec("boom", kind="linear", unit="mm")),
        rate_hz=20.0,
    )
    n = 50
    theta = np.tile(np.linspace(0.4, 0.5, n)[:, None], (1, 2))  # [rad], [m]
    raw = Episode(
        spec=spec,
        time=np.arange(n) * spec.dt,
        u=np.zeros((n, 2)),
        theta=theta,
        omega=np.full((n, 2), 2.0),  # [rad/s], [m/s]
        theta_true=theta,
        omega_true=np.full((n, 2), 0.04),
    )
    ax = _figure_of(monkeypatch, raw=raw, cleaned=raw, joint="boom", path=tmp_path / "b.png")
    assert ax.get_ylabel() == "boom stroke [mm]"
    raw_line, intg, fused, truth = ax.lines[:4]
    np.testing.assert_allclose(fused.get_ydata(), 1000 * theta[:, 1])
    np.testing.assert_allclose(raw_line.get_ydata(), 1000 * theta[:, 1])
    np.testing.assert_allclose(truth.get_ydata(), 1000 * theta[:, 1])
    np.testing.assert_allclose(intg.get_ydata()[1] - intg.get_ydata()[0], 1000 * 2.0 * spec.dt)
    assert raw_line.get_label().startswith("raw stroke")
    ax = _figure_of(monkeypatch, raw=raw, cleaned=raw, joint="swing", path=tmp_path / "s.png")
    assert ax.get_ylabel() == "swing angle [rad]"
    np.testing.assert_allclose(ax.lines[0].get_ydata(), theta[:, 0])
    assert ax.lines[0].get_label() == r"raw angle $\theta_t$"
    assert ax.lines[1].get_label() == r"integrated gyro $\theta^{intg}_t$"
