"""The ensemble of two kinds of network, joint by joint: :func:`composite`.

A plain network (trained from scratch) and a map-correcting one (``prior``: it corrects the
static valve map) merge into one network once the plain one carries the map with zero gains
(:func:`in_prior_form`); :func:`~excavator_surrogate.surrogate.ensemble.merge` with
``joint_weights`` then weighs each joint's output by kind.  :mod:`.kinds` chooses the
weights; :func:`plain_ensemble` pairs each plain network with its twin trained the other way
on the exogenous inputs (:mod:`.variants`).
"""

from __future__ import annotations

from collections.abc import Sequence

from ..surrogate.ensemble import merge
from ..surrogate.model import Surrogate
from ..surrogate.prior import PRIOR_MAP
from ..surrogate.series import with_map_joints


def in_prior_form(plain: Surrogate, prior: Surrogate) -> Surrogate:
    """``plain`` (no map) as a network that reads ``prior``'s features and carries its map
    with zero gains: the same output, ready to be merged with ``prior``."""
    p = prior.net.prior
    n_joint = plain.spec.n_joint
    fit = {k: getattr(p, k).tolist() for k in PRIOR_MAP}  # no joint on it: gains 0
    return with_map_joints(plain, fit, [False] * n_joint, lags=prior.norm.lags or None)


def plain_ensemble(
    plains: Sequence[Surrogate],
    *,
    twins: Sequence[Surrogate] | None = None,
    twin_joints: Sequence[bool] | None = None,
) -> Surrogate:
    """The plain networks' ensemble: their merge.  With ``twins`` (network ``i``'s twin: the
    same seed, trained the other way on the exogenous inputs, :mod:`.variants`), each seed's
    two networks first become one whose joint ``j`` is the twin's where ``twin_joints[j]``,
    else the plain one's (:func:`~excavator_surrogate.surrogate.ensemble.merge` with
    ``joint_weights``), and the seeds' pairs are merged as the ensemble's members."""
    if twins is None:
        return merge(list(plains))
    if len(twins) != len(plains) or not plains:
        raise ValueError(f"{len(twins)} and {len(plains)} networks do not pair up")
    s = [1.0 if j else 0.0 for j in _twin_joints(twin_joints, plains)]
    pairs = [
        merge([t, p], joint_weights=[s, [1.0 - x for x in s]], name=f"{t.name}-inputs-paired")
        for t, p in zip(twins, plains)
    ]
    return merge(pairs) if len(pairs) > 1 else pairs[0]


def _twin_joints(twin_joints: Sequence[bool] | None, plains: Sequence[Surrogate]) -> list[bool]:
    n_joint = plains[0].spec.n_joint
    if twin_joints is None or len(twin_joints) != n_joint:
        raise ValueError(f"twin_joints {twin_joints} is not one flag per joint ({n_joint})")
    return list(twin_joints)


def composite(
    plains: Sequence[Surrogate],
    priors: Sequence[Surrogate],
    use_prior: Sequence[float],
    *,
    twins: Sequence[Surrogate] | None = None,
    twin_joints: Sequence[bool] | None = None,
) -> Surrogate:
    """The ensemble whose joint ``j`` is ``a_j`` times the map-correcting networks' mean plus
    ``1 - a_j`` times the plain networks' mean, ``a = use_prior``.

    Args:
        plains: K plain networks; priors: P map-correcting networks, P dividing K.
        use_prior: (n_joint,) the map-correcting networks' weight ``a_j`` in [0, 1] per joint
            (a bool: which joints they drive; 1/2: the even blend of both kinds).
        twins, twin_joints: the plain side as :func:`plain_ensemble` pairs: plain network
            ``i``'s share of joint ``j`` goes to ``twins[i]`` where ``twin_joints[j]``.

    Returns:
        All 0 or all 1: the plain (:func:`plain_ensemble`) or the map-correcting ensemble.
        Else the merge of P composites, group ``g`` = plain networks ``g, g + P, ...``
        (weight ``(1 - a_j) P / K`` each on joint ``j``; with twins, that weight goes to
        the network of the pair that drives joint ``j``, and a network with no weight left
        is left out) and map-correcting network ``g`` (weight ``a_j``).
    """
    a = [float(x) for x in use_prior]
    if not all(0.0 <= x <= 1.0 for x in a):
        raise ValueError(f"the map-correcting networks' weights {a} are not in [0, 1]")
    if not any(a):
        return plain_ensemble(plains, twins=twins, twin_joints=twin_joints)
    if all(x == 1.0 for x in a):
        return merge(list(priors))
    n_prior = len(priors)
    if len(plains) % n_prior:
        raise ValueError(f"{len(priors)} map-correcting networks do not divide {len(plains)}")
    if twins is not None and len(twins) != len(plains):
        raise ValueError(f"{len(twins)} and {len(plains)} networks do not pair up")
    n_group = len(plains) // n_prior  # plain networks (or pairs) per group
    w_plain = [(1.0 - x) / n_group for x in a]
    # each plain network's share of its seed's plain weight, per joint (with its twin's)
    shares: list[tuple[Sequence[Surrogate], list[float]]] = [(plains, [1.0] * len(a))]
    if twins is not None:
        s = [1.0 if j else 0.0 for j in _twin_joints(twin_joints, plains)]
        shares = [(plains, [1.0 - x for x in s]), (twins, s)]
    groups = []
    for g, b in enumerate(priors):
        nets, weights = [], []
        for i in range(g, len(plains), n_prior):
            for side, share in shares:
                w = [wp * x for wp, x in zip(w_plain, share)]
                if twins is None or any(w):
                    nets.append(in_prior_form(side[i], b))
                    weights.append(w)
        groups.append(merge([*nets, b], joint_weights=[*weights, a], name=f"{b.name}-composite"))
    return merge(groups)
