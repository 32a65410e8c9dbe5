"""Closed-loop validation score of a surrogate: :func:`free_run_error`.

Model selection (training, baselines, sweeps) ranks candidates by it: the model is rolled out
in closed loop on the validation episodes; ``val_error`` = mean over joints of
RMSE(theta) / std(theta_ref) after the warm-up (:func:`score_runs`).  :func:`free_run_errors` scores several
candidates of one architecture in one batched free run (:mod:`.stacked`), stepped in NumPy
(:mod:`.numpy_loop`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..data.episode import Episode
from .model import Surrogate
from .numpy_loop import numpy_capable, rollout_episodes_numpy
from .rollout import EpisodeRollout, rollout_episodes
from .scores import regression_metrics, scored_angles
from .stacked import stack, stackable


def free_run_error(
    sur: Surrogate, episodes: list[Episode], *, max_steps: int | None = None
) -> dict[str, Any]:
    """Closed-loop validation: roll out ``episodes`` and score the angle after the warm-up.

    Returns:
        ``{"val_error": mean_j RMSE_j / std_j(theta_ref), "theta_rmse": [...], "theta_r2": [...],
        "omega_rmse": [...]}`` (per joint lists); ``val_error`` is ``inf`` if the rollout diverged.
    """
    sur.net.eval()
    return score_runs(rollout_episodes(sur, episodes, max_steps=max_steps), sur)


def with_val_scores(model: Surrogate, got: Mapping[str, Any]) -> Surrogate:
    """``model`` with its own validation free-run scores ``got`` (:func:`free_run_error`) in
    its metrics (``val_error``, ``val``, ``best_val_error``): a model that a choice after
    training changed records its own validation, not that of the model it came from."""
    model.metrics = {
        **(model.metrics or {}),
        "val_error": got["val_error"],
        "val": dict(got),
        "best_val_error": got["val_error"],
    }
    return model


def free_run_errors(
    surs: list[Surrogate], episodes: list[Episode], *, max_steps: int | None = None
) -> list[dict[str, Any]]:
    """:func:`free_run_error` of each of ``surs`` (a training's candidates): in one batched
    free run when they differ only in their weights (:func:`~.stacked.stackable`, e.g. a
    training's raw and averaged weights), else one after the other; stepped in NumPy where
    it can (:mod:`.numpy_loop`: about 2.5x faster on a long segment).  The scores equal
    :func:`free_run_error`'s to float32 rounding; a candidate that diverges scores ``inf``
    without touching the others (no operation mixes two candidates' rows)."""
    if not stackable(surs):
        return [score_runs(_free_runs(s, episodes, max_steps=max_steps), s) for s in surs]
    n = len(episodes)
    runs = _free_runs(stack(surs), list(episodes) * len(surs), max_steps=max_steps)
    return [score_runs(runs[c * n : (c + 1) * n], s) for c, s in enumerate(surs)]


def _free_runs(
    sur: Surrogate, episodes: list[Episode], *, max_steps: int | None
) -> list[EpisodeRollout]:
    """The free runs of a training's candidate(s): stepped in NumPy where it can."""
    sur.net.eval()
    run = rollout_episodes_numpy if numpy_capable(sur) else rollout_episodes
    return run(sur, episodes, max_steps=max_steps)


def score_runs(runs: list[EpisodeRollout], sur: Surrogate) -> dict[str, Any]:
    """The scores of :func:`free_run_error` from the free runs ``runs`` of ``sur``: the angles
    as the CBE report scores them (:func:`~.scores.scored_angles`), except that each run's
    periodic joint stays on its own turn::

        val_error = mean over moving joints j of RMSE_j / max(std_j(theta_ref), 1e-6)

    Turning the runs to one another (as the report's R^2 does) would re-weight a swing's
    error in ``val_error`` and move its R^2, which decides whether a swing follows its map
    (:mod:`~..training.map_joints`), so change the models selected on data whose validation
    runs lie on different turns.  A joint constant in every validation run has no scale to
    normalise by and no R^2 (NaN): it is left out of ``val_error`` (its RMSE is recorded),
    unless no joint moves, when ``val_error`` is the mean RMSE.
    """
    pred, ref, still = scored_angles(runs, sur.spec, align_turns=False)
    eo = np.concatenate([r.omega_hat[r.warmup :] - r.omega_ref[r.warmup :] for r in runs])
    m = regression_metrics(pred, ref, still=still)
    rmse = m["rmse"]
    with np.errstate(invalid="ignore", divide="ignore"):
        scaled = rmse / np.maximum(ref.std(axis=0), 1e-6)
    val = float(np.mean(scaled[~still] if (~still).any() else rmse))
    if not math.isfinite(val):
        val = math.inf
    return {
        "val_error": val,
        "theta_rmse": [float(v) for v in rmse],
        "theta_r2": [float(v) for v in m["r2"]],
        "omega_rmse": [float(v) for v in np.sqrt(np.mean(eo**2, axis=0))],
    }
