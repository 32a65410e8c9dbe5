"""The static map choice on one validation segment: a candidate must hold on both halves.

The map choice (:mod:`.map_joints`) makes a joint a candidate for the static valve map when
the map's angle RMSE over the whole validation free run is at most ``MAP_TIE`` above the
network's.  Where validation is one segment of one log, that is one draw: a single excursion
in it can decide.  So, with ``[train] map_blocks`` (the recipe's), a candidate on a single
validation episode must also tie or beat the network on **both of its halves**, each
free-run from its own warm-up (no check when a half holds fewer scored samples than its
warm-up).  Several validation episodes are pooled as before.

Evidence (``docs/real-history.md``, session 100; computer B, seeds 0 / 10 / 20):

- the continuous log's boom went to the map in seed 20, 20 % better than the networks on
  the whole 100-s segment and 26 % worse on its first half; the map then ran the test 2.7x
  worse (4.11 against 1.54 deg) and the next 8 test segments 7 % worse.  Kept on its
  networks, the boom's worst seed falls from 2.11x to 1.10x the median;
- the 7-minute loader's boom, on the map in seeds 0 and 10 (a tie on the first half, 31-45 %
  worse on the second): the test median 4.06 -> 3.06 deg, the log's continuation 4.80 ->
  5.23 deg (the structured model's 3.03 and 5.37); on another simulated 7-minute log the
  one seed it changed traded the other way (test 3.11 -> 3.74, continuation 5.01 -> 4.43);
- with two validation sessions as blocks, the second sessions log's arm would have left the
  map in seed 10 (lost one session of two) and scored the test 12 % and the 12 more
  sessions 10 % worse: so episodes are not blocks.

The check adds one free run of the network and one of each map variant the joints use over
the two halves, and only when some joint is a candidate.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..data.episode import Episode
from ..surrogate.model import Surrogate
from ..surrogate.rollout import rollout_episodes
from ..surrogate.series import with_map_joints
from ..surrogate.validation import free_run_error, score_runs


def all_on_map(
    sur: Surrogate,
    fit: Mapping[str, Any],
    val: Sequence[Episode],
    *,
    stops: tuple[Any, Any] | None,
    max_steps: int | None,
) -> dict[str, Any]:
    """The validation free run of ``sur`` with every joint on the map ``fit``: a map joint's
    angle depends on its own command only, so each joint scores as its map alone."""
    return free_run_error(_on_map(sur, fit, stops), list(val), max_steps=max_steps)


def _on_map(sur: Surrogate, fit: Mapping[str, Any], stops: tuple[Any, Any] | None) -> Surrogate:
    """``sur`` with every joint on the map ``fit`` (stopping at ``stops``)."""
    return with_map_joints(sur, fit, [True] * sur.spec.n_joint, map_stops=stops)


def validation_blocks(
    val: Sequence[Episode], *, warmup: int, max_steps: int | None = None
) -> tuple[list[Episode], str]:
    """The blocks a candidate joint must hold on, and what they are in words.

    Args:
        val: the validation episodes.
        warmup: the free run's warm-up [samples] (the network's window).
        max_steps: the validation free run's length cap [samples] (None: whole episodes);
            the episode is cut to it before it is halved, as its free run would be.

    Returns:
        ``(blocks, what)``: a single episode's two halves if each has at least ``warmup``
        samples after its own warm-up; else ``([], why not)``.  Several episodes are not
        blocks: their pooled free run already weighs separate runs (on the sessions logs,
        days at different oil temperatures, where the map's worth is its mean over days).
    """
    if len(val) != 1:
        return [], f"{len(val)} validation episodes: their pooled free run decides"
    ep = val[0]
    n = min(ep.n_step, max_steps) if max_steps else ep.n_step
    half = n // 2
    if half < 2 * warmup:
        return [], f"one validation episode of {n} samples, too short to halve"
    return [ep.slice(0, half), ep.slice(half, 2 * half)], "the validation episode's halves"


def block_scores(
    sur: Surrogate,
    fits: Sequence[Mapping[str, Any]],
    pick: Sequence[int],
    blocks: Sequence[Episode],
    *,
    stops: tuple[Any, Any] | None,
    max_steps: int | None = None,
) -> tuple[list[list[float]], list[list[float]]]:
    """Each block's angle RMSE per joint [rad], ``(network, map)``: (n_block, n_joint) each,
    the map's per joint from its variant ``pick[j]`` of ``fits``; every model runs all the
    blocks in one batched free run (each cut to ``max_steps``), and a variant no joint picks
    does not run."""

    def per_block(model: Surrogate) -> list[list[float]]:
        model.net.eval()
        runs = rollout_episodes(model, list(blocks), max_steps=max_steps)
        return [score_runs([r], model)["theta_rmse"] for r in runs]

    net = per_block(sur)
    maps = {v: per_block(_on_map(sur, fits[v], stops)) for v in sorted(set(pick))}
    on_map = [[maps[v][b][j] for j, v in enumerate(pick)] for b in range(len(blocks))]
    return net, on_map


def held_on_blocks(
    net: Sequence[Sequence[float]], on_map: Sequence[Sequence[float]], *, tie: float
) -> list[bool]:
    """Per joint: whether the map's angle RMSE is at most ``1 + tie`` times the network's on
    more than half of the blocks (both of two) (``net``, ``on_map``: (n_block, n_joint), from
    :func:`block_scores`)."""
    n_block, n_joint = len(net), len(net[0])
    return [
        2 * sum(on_map[b][j] <= (1 + tie) * net[b][j] for b in range(n_block)) > n_block
        for j in range(n_joint)
    ]


def check_blocks(
    sur: Surrogate,
    fits: Sequence[Mapping[str, Any]],
    pick: Sequence[int],
    val: Sequence[Episode],
    check: Sequence[bool],
    *,
    stops: tuple[Any, Any] | None,
    max_steps: int | None,
    names: Sequence[str],
    tie: float,
) -> dict[str, Any] | None:
    """The block check of the candidates ``check`` (n_joint,), each on its map variant
    ``pick[j]`` of ``fits``: its record, whose ``refused`` names the joints whose map is not
    within ``1 + tie`` times the network's angle RMSE on more than half of the blocks, or None
    if there is nothing to check (no candidate, or no blocks)."""
    split, what = validation_blocks(val, warmup=sur.window, max_steps=max_steps)
    if not any(check) or not split:
        return None
    net_b, map_b = block_scores(sur, fits, pick, split, stops=stops, max_steps=max_steps)
    held = held_on_blocks(net_b, map_b, tie=tie)
    return {
        "what": what,
        "tie": tie,
        "checked": [n for n, c in zip(names, check) if c],
        "val_theta_rmse_network": net_b,
        "val_theta_rmse_map": map_b,
        "refused": [n for n, c, h in zip(names, check, held) if c and not h],
    }
