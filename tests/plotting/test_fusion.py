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
