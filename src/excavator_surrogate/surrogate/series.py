"""A network with some joints on the static valve map *in series*: :func:`with_map_joints`.

The map drives those joints' angles and the network reads them, as it reads every joint's;
the network's output for them is dropped, the other joints keep it exactly.  The parallel
composition, where the network keeps reading its own angle of a map joint, is
:func:`.parallel.with_parallel_map`; both give a map joint's ensemble members the map's gain
spread (:func:`member_offsets`, :func:`.structured.gain_spread`) and read a delayed map's
command through zero-weight columns (:func:`with_lag_columns`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import torch

from .envelope import with_end_stops
from .features import Normalization
from .model import Surrogate
from .prior import PRIOR_MAP


def member_offsets(n_member: int) -> torch.Tensor:
    """(n_member,) float64 fixed offsets, evenly spaced, mean 0 and standard deviation 1
    (ddof 1): the members' places in a map joint's gain spread (:func:`with_map_joints`)."""
    z = torch.linspace(-1.0, 1.0, n_member, dtype=torch.float64)
    return z / z.std() if n_member > 1 else z * 0.0


def with_lag_columns(
    norm: Normalization, state: dict[str, torch.Tensor], lags: Sequence[int]
) -> Normalization:
    """``norm`` with delayed-command features ``lags`` (:meth:`.Normalization.with_lags`),
    and the network weights ``state`` (a ``state_dict``, changed in place) given zero weights
    for those columns in their first layer: the network's output does not change (up to the
    order of float sums).  Returns the new normalisation."""
    new = norm.with_lags(lags)
    at, n_joint = new.lag_start, len(new.periodic)  # the delayed commands' columns
    w = state["rnn.weight_ih_l0"]  # (gates, n_feature)
    state["rnn.weight_ih_l0"] = torch.cat([w[:, :at], w.new_zeros(len(w), n_joint), w[:, at:]], 1)
    return new


def with_map_joints(
    sur: Surrogate,
    fit: Mapping[str, Sequence[float]],
    joints: Sequence[bool],
    *,
    lags: Sequence[int] | None = None,
    map_stops: tuple[Sequence[float], Sequence[float]] | None = None,
) -> Surrogate:
    """A copy of ``sur`` whose ``joints`` move by the static map ``fit`` alone (the network's
    output for them is dropped) while the other joints keep the network's output exactly.

    Built with a :class:`~.prior.SpeedPrior` whose gains are ``fit``'s on ``joints`` and zero
    elsewhere, the head's output rows of ``joints`` zeroed, and ``y_mean / y_std`` added to the
    other rows' bias (the prior subtracts it from every joint)::

        map joint j:    omega_j = y_std (0) + s_j(u)                 = s_j(u)
        other joint j:  omega_j = y_std (head_j + y_mean_j / y_std_j) = the network's omega_j

    A network that already corrects a map (``model_cfg.prior``) keeps it on the other joints
    (its head carries no ``y_mean``, so no bias moves).

    A joint whose map has a delay ``d_j > 0`` (``fit["delay"]``) reads its command ``d_j``
    samples back: the copy's features get the delayed commands (:meth:`.Normalization.with_lags`,
    carried as a delay line in the command state ``z`` by every runtime), and the network's
    first layer gets zero weights for those columns, so the other joints' output is the
    network's (up to the order of float sums).  Without delays the copy's features are the
    network's.  If ``sur`` already reads delayed commands, a map joint's delay must be its
    feature's, or 0 (the map then reads the current command's column).

    A merged ensemble's member biases are moved alike, and member ``m`` drives a map joint
    with the gain ``1 + sigma_j z_m`` (``metrics["ensemble"]["map_gain_dev"]``, (M, n_joint),
    ``sigma_j`` the map's ``gain_spread``, ``z`` fixed, mean 0 and standard deviation 1 over
    the members): the merged network's own output (their mean) is the map exactly, and the
    members' spread on a map joint is ``sigma_j |s_j(u)|``, integrated in the angle.  The other
    joints still read the map joints' angles, now the map's.

    Args:
        sur: an LSTM/GRU surrogate without a residual head.
        fit: :func:`.structured.fit_prior`'s map (``cols``, ``a_pos``, ``a_neg``, ``k_pos``,
            ``k_neg`` and optionally ``delay`` and ``gain_spread``; per joint).
        joints: (n_joint,) which joints follow the map.
        lags: (n_joint,) the delayed-command features to give a network without them
            (default: each map joint's delay, 0 elsewhere); e.g. those of another network
            this one is to be merged with.
        map_stops: ``(lo, hi)``, (n_joint,) each [rad], the map joints' end stops (the
            copy's spec; +-inf: none), or None: ``sur``'s.  Ignored without end stops.

    Returns:
        A new surrogate (``model_cfg.prior`` set; ``metrics["map_joints"]`` names the joints).

    Raises:
        ValueError: a residual head or ARX; a map delay that the features cannot read.
    """
    if sur.model_cfg.residual or sur.model_cfg.cell == "arx":
        raise ValueError("with_map_joints needs an LSTM/GRU without a residual head")
    pick = torch.tensor([bool(j) for j in joints])
    spec = sur.spec
    n_joint = spec.n_joint
    delay = [int(d) for d in fit.get("delay", [0] * n_joint)]
    old = sur.net.prior if sur.model_cfg.prior else None
    norm = sur.norm
    state = {k: v.detach().clone() for k, v in sur.net.state_dict().items()}
    if not norm.lags:
        want = (
            [int(d) for d in lags]
            if lags is not None
            else [d if p else 0 for d, p in zip(delay, pick.tolist())]
        )
        if any(want):
            norm = with_lag_columns(norm, state, want)
    elif lags is not None and tuple(int(d) for d in lags) != norm.lags:
        raise ValueError(f"with_map_joints: this network already reads the delays {norm.lags}")

    def col(j: int) -> int:
        """The feature column that map joint ``j`` reads."""
        if norm.lags and norm.lags[j] == delay[j]:
            return norm.lag_start + j
        if delay[j] == 0:
            return spec.n_angle_feature + j  # the current command
        raise ValueError(
            f"with_map_joints: joint {spec.names[j]}'s map delay {delay[j]} is not a feature "
            f"of this network (its delays {norm.lags or 'none'})"
        )

    cfg = replace(sur.model_cfg, prior=True, n_feature=norm.n_feature)
    net = type(sur.net)(cfg)
    missing = net.load_state_dict(state, strict=False).missing_keys
    assert all(k.startswith("prior.") for k in missing), missing
    base = {n: getattr(old, n).tolist() for n in PRIOR_MAP} if old is not None else None

    if base is not None:
        keep = base["cols"]
    else:  # gain 0: any column; the delayed or current command, as fit_prior would say
        keep = [
            norm.lag_start + j if norm.lags else spec.n_angle_feature + j for j in range(n_joint)
        ]

    def on(name: str) -> list[float]:
        """The map's ``name`` per joint: ``fit``'s on ``joints``, the old map's (or 0) elsewhere."""
        return [
            float(v) if p else (base[name][j] if base is not None else 0.0)
            for j, (v, p) in enumerate(zip(fit[name], pick.tolist()))
        ]

    net.prior.load_fit(
        cols=[col(j) if p else keep[j] for j, p in enumerate(pick.tolist())],
        a_pos=on("a_pos"),
        a_neg=on("a_neg"),
        k_pos=on("k_pos"),
        k_neg=on("k_neg"),
        norm=norm,
    )
    # a network without a map carries y_mean in its head: the prior now subtracts it
    shift = (
        torch.zeros(n_joint)
        if old is not None
        else (norm.y_mean / norm.y_std).detach().float().cpu()
    )
    last = net.head[2]
    with torch.no_grad():
        last.weight[pick] = 0.0
        last.bias[pick] = 0.0
        last.bias[~pick] += shift.to(last.bias)[~pick]
    metrics = dict(sur.metrics or {})
    ens = metrics.get("ensemble")
    if isinstance(ens, dict) and "member_bias" in ens:
        mb = torch.tensor(ens["member_bias"], dtype=torch.float64)  # (M, n_joint)
        mb[:, pick] = 0.0
        mb[:, ~pick] += shift.double()[~pick]
        metrics["ensemble"] = {**ens, "member_bias": mb.tolist()}
        if "gain_spread" in fit:  # (M, n_joint) each member's gain deviation on the map joints
            sigma = torch.tensor(
                [float(v) if p else 0.0 for v, p in zip(fit["gain_spread"], pick.tolist())],
                dtype=torch.float64,
            )
            dev = member_offsets(mb.shape[0])[:, None] * sigma[None, :]
            if "map_gain_dev" in ens:  # earlier map joints keep theirs
                prev = torch.tensor(ens["map_gain_dev"], dtype=torch.float64)
                dev[:, ~pick] = prev[:, ~pick]
            metrics["ensemble"]["map_gain_dev"] = dev.tolist()
    before = set(metrics.get("map_joints") or [])
    metrics["map_joints"] = [n for n, p in zip(spec.names, pick.tolist()) if p or n in before]
    if map_stops is not None and sur.end_stops:
        spec = with_end_stops(spec, *map_stops, joints=pick.tolist())
    return Surrogate(
        net=net.train(sur.net.training),
        spec=spec,
        norm=norm,
        model_cfg=cfg,
        mode=sur.mode,
        train_config=dict(sur.train_config or {}),
        metrics=metrics,
        name=sur.name,
        end_stops=sur.end_stops,
    )
