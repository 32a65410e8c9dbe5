"""Baselines for the CBE table: linear ARX by least squares (the GRU is ``TrainConfig(cell="gru")``)
and the structured per-joint model (dead zone, gain, delay, end stops; :mod:`.structured`).

The ARX model uses exactly the surrogate's inputs: the normalised feature window of ``W``
samples (angles or sin/cos, scaled commands) -> normalised ``omega[t+1]``, i.e.
``y = A vec(x[t-W+1..t]) + b``.  It is fitted one-step-ahead by (ridge-regularised) least squares
on the training split (ridge weight chosen by free-run error on the validation split) and rolled
out in closed loop exactly like the LSTM (windowed mode).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from numpy.lib.stride_tricks import sliding_window_view

from ..data.episode import Episode
from ..errors import DataError
from ..spec import MachineSpec
from .angles import omega_in_np, omega_target
from .features import Normalization
from .model import ARXNet, ModelConfig, Surrogate
from .structured import fit_structured

__all__ = ["DEFAULT_RIDGE", "RIDGES", "fit_arx", "fit_structured"]

RIDGES = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2)
"""Candidate relative ridge weights searched on the validation split."""
DEFAULT_RIDGE = 1e-3
"""Relative ridge weight without validation data."""


def fit_arx(
    episodes: Sequence[Episode],
    *,
    window: int = 30,
    spec: MachineSpec | None = None,
    norm: Normalization | None = None,
    ridge: float | None = None,
    val: Sequence[Episode] = (),
    ridges: Sequence[float] = RIDGES,
    end_stops: bool = False,
) -> Surrogate:
    """Fit the linear ARX baseline on ``episodes`` (training split).

    Args:
        episodes: training episodes (each longer than ``window``).
        window: W [samples].
        spec: machine spec (default: the first episode's).
        norm: feature/target normalisation (default: fitted on ``episodes``); pass the LSTM's
            to share it.
        ridge: Tikhonov weight relative to the mean diagonal of the normal matrix.  None: pick
            from ``ridges`` by closed-loop angle error on ``val`` (or :data:`DEFAULT_RIDGE` without
            ``val``).  Least squares on a window of nearly collinear angles is ill-conditioned and
            unregularised ARX models often oscillate in free run, so the choice matters.
        val: validation episodes for choosing ``ridge``.
        ridges: candidate ridge weights.
        end_stops: clip free-run angles to the spec's joint limits (as the LSTM it is compared
            with does).

    Returns:
        A windowed :class:`Surrogate` named ``arx`` (``metrics["ridge"]`` is the weight used).
    """
    if not episodes:
        raise DataError(None, "no training episodes to fit the ARX baseline")
    spec = spec or episodes[0].spec
    if norm is None:
        norm = Normalization.fit([e.theta for e in episodes], [e.u for e in episodes], spec)
    n_in = window * norm.n_feature + 1
    gram = np.zeros((n_in, n_in))
    rhs = np.zeros((n_in, spec.n_joint))
    y_mean = norm.y_mean.double().numpy()
    y_std = norm.y_std.double().numpy()
    n_rows = 0
    for ep in episodes:
        if ep.n_step <= window:
            continue
        z = norm.play_from_rest_np(ep.u, spec)
        w = omega_in_np(ep.theta, spec) if norm.omega_in else None
        x = norm.encode_np(ep.theta, ep.u, spec, z, w)
        y = (omega_target(ep.theta, spec) - y_mean) / y_std
        win = sliding_window_view(x, window, axis=0)  # (n_step-W+1, n_feature, W)
        phi = win.transpose(0, 2, 1).reshape(win.shape[0], -1)[:-1]  # windows ending at t=W-1..N-2
        phi = np.concatenate([phi, np.ones((phi.shape[0], 1))], axis=1)
        tgt = y[window:]
        gram += phi.T @ phi
        rhs += phi.T @ tgt
        n_rows += phi.shape[0]
    if n_rows == 0:
        raise DataError(None, f"no training episode is longer than the window ({window})")
    cfg = ModelConfig(n_feature=norm.n_feature, n_joint=spec.n_joint, window=window, cell="arx")
    scale = float(np.trace(gram)) / n_in

    def solve(r: float) -> Surrogate:
        coef = np.linalg.solve(gram + r * scale * np.eye(n_in), rhs)  # (n_in, n_joint)
        net = ARXNet(cfg)
        with torch.no_grad():
            net.linear.weight.copy_(torch.as_tensor(coef[:-1].T, dtype=torch.float32))
            net.linear.bias.copy_(torch.as_tensor(coef[-1], dtype=torch.float32))
        net.eval()
        return Surrogate(
            net=net,
            spec=spec,
            norm=norm,
            model_cfg=cfg,
            mode="windowed",
            train_config={"baseline": "arx", "ridge": r, "window": window},
            metrics={"n_rows": n_rows, "ridge": r},
            name="arx",
            end_stops=end_stops,
        )

    if ridge is not None:
        return solve(ridge)
    val = [e for e in val if e.n_step > window + 1]
    if not val:
        return solve(DEFAULT_RIDGE)
    from .validation import free_run_error

    best, best_err = None, np.inf
    for r in ridges:
        cand = solve(r)
        err = free_run_error(cand, list(val))["val_error"]
        if err < best_err or best is None:
            best, best_err = cand, err
    best.metrics["val_error"] = best_err
    return best
