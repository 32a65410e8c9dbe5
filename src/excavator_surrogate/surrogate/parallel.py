"""A network with some joints on the static valve map *in parallel*: :func:`with_parallel_map`.

The map drives those joints' reported angles, while the network keeps reading its own angle
of them (:mod:`.own_angles`), so its free run is the network's own, and each joint scores
exactly as its source scores alone.  The series composition, where the network reads the
map's angle, is :func:`.series.with_map_joints`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import torch

from .angles import joint_limits
from .envelope import with_end_stops
from .model import Surrogate
from .own_angles import OwnMap
from .series import member_offsets, with_lag_columns


def with_parallel_map(
    sur: Surrogate,
    fit: Mapping[str, Sequence[float]],
    joints: Sequence[bool],
    *,
    lags: Sequence[int] | None = None,
    map_stops: tuple[Sequence[float], Sequence[float]] | None = None,
) -> Surrogate:
    """A copy of ``sur`` whose ``joints`` report the static map ``fit``'s speed and angle
    while its network runs as before, reading its own angles of them.

    With ``map_stops`` the map joints' reported angles stop there (the copy's spec), and the
    network's own angles keep ``sur``'s end stops (:attr:`.own_angles.OwnMap.theta_min`), so
    the network's free run is still its own.

    The network's weights are ``sur``'s.  A map with a delay ``d_j > 0`` reads the command
    ``d_j`` samples back from the command delay line: a network without delayed-command
    features gets them (:meth:`.features.Normalization.with_lags`) with zero weights in its
    first layer, so its output is unchanged (up to the order of float sums); one with them
    must hold ``d_j`` in its line.  With a merged ensemble's members, member ``m`` drives a
    map joint with the gain ``1 + sigma_j z_m`` (``metrics["ensemble"]["own_gain_dev"]``, as
    :func:`.series.with_map_joints` does): their mean is the map, their spread the map's
    gain spread (``fit["gain_spread"]``) times the distance it moved the joint.

    Args:
        sur: an LSTM/GRU surrogate without joints on a map in parallel.
        fit: :func:`.structured.fit_prior`'s map (``a_pos``, ``a_neg``, ``k_pos``, ``k_neg``
            and optionally ``delay`` and ``gain_spread``; per joint).
        joints: (n_joint,) which joints follow the map (at least one).
        lags: (n_joint,) delayed-command features to give a network without them (default:
            each map joint's delay, 0 elsewhere).
        map_stops: ``(lo, hi)``, (n_joint,) each [rad], the map joints' end stops (+-inf:
            none; e.g. the training range, as :func:`.structured.fit_structured`'s), or None:
            ``sur``'s.  Ignored when ``sur`` runs without end stops.

    Returns:
        A new surrogate (``norm.own`` set; ``metrics["map_joints"]`` names the joints,
        ``metrics["map_parallel"]`` is True).

    Raises:
        ValueError: an ARX network, no joint, joints already on a map in parallel, or a map
            delay the delay line cannot hold.
    """
    if sur.model_cfg.cell == "arx":
        raise ValueError("with_parallel_map needs an LSTM/GRU network")
    if sur.norm.own is not None:
        raise ValueError("with_parallel_map: this network already has joints on a map")
    spec = sur.spec
    pick = [bool(j) for j in joints]
    own = OwnMap.from_fit(fit, pick)
    norm = sur.norm
    state = {k: v.detach().clone() for k, v in sur.net.state_dict().items()}
    cfg = sur.model_cfg
    want = [int(d) for d in lags] if lags is not None else list(own.delay)
    if not norm.lags and any(want):
        norm = with_lag_columns(norm, state, want)  # read with zero weights
        cfg = replace(cfg, n_feature=norm.n_feature)
    if map_stops is not None and sur.end_stops:
        own = own.with_stops(*joint_limits(spec))  # the network's, for its own rows
        spec = with_end_stops(spec, *map_stops, joints=pick)
    norm = norm.with_own(own)  # raises if the line cannot hold a delay
    net = type(sur.net)(cfg)
    net.load_state_dict(state)
    metrics = dict(sur.metrics or {})
    ens = metrics.get("ensemble")
    if isinstance(ens, dict) and "member_bias" in ens and "gain_spread" in fit:
        sigma = torch.tensor(
            [float(v) if p else 0.0 for v, p in zip(fit["gain_spread"], pick)],
            dtype=torch.float64,
        )
        dev = member_offsets(len(ens["member_bias"]))[:, None] * sigma[None, :]
        metrics["ensemble"] = {**ens, "own_gain_dev": dev.tolist()}
    metrics["map_joints"] = [n for n, p in zip(spec.names, pick) if p]
    metrics["map_parallel"] = True
    return replace(
        sur,
        spec=spec,
        net=net.to(sur.device, sur.dtype).train(sur.net.training),
        norm=norm.to(sur.device, sur.dtype),
        model_cfg=cfg,
        train_config=dict(sur.train_config or {}),
        metrics=metrics,
    )


def own_gain_dev(sur: Surrogate) -> torch.Tensor:
    """(M, n_joint) float64: each ensemble member's gain deviation on the joints on a map in
    parallel (``metrics["ensemble"]["own_gain_dev"]``; zeros where there is none, (1,
    n_joint) zeros for a single network)."""
    ens = (sur.metrics or {}).get("ensemble")
    n_joint = sur.spec.n_joint
    if isinstance(ens, dict) and "own_gain_dev" in ens:
        return torch.tensor(ens["own_gain_dev"], dtype=torch.float64).reshape(-1, n_joint)
    n = len(ens["member_bias"]) if isinstance(ens, dict) and "member_bias" in ens else 1
    return torch.zeros(n, n_joint, dtype=torch.float64)
