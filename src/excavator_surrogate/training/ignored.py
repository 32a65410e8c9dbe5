"""Exogenous inputs a network ignores: trained without their columns, stored with them.

With ``[train] exogenous = "ignore"`` a network must not depend on the data's exogenous
inputs (the recipe's rule where validation vouches for none, :mod:`.auto`; the losing way
of the input choice, :mod:`.variants`).  Holding their input weights at zero (the way
before session 95) gives a network that cannot read them, yet trains as another draw than
the one without the columns: the first layer's sums run over more terms and round
differently, so an input the recipe refused could still move the result by a few percent.

So the training runs on the data without the inputs (:func:`without_inputs`): the same
arrays, sizes, plan and seeds as a dataset that never had them, hence the same network
bit for bit.  What it writes is then given the columns back (:func:`widened`), with zero
input weights, so the checkpoint takes the machine's full command vector like any other::

    W_ih = [W[:, :at], 0, W[:, at:]]        at = the inputs' first feature column

and a resumed run takes them away again (:func:`narrowed`).  The optimiser state in a
checkpoint stays the training's, without the columns.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch

from ..data.dataset import Dataset
from ..data.episode import Episode
from ..errors import CheckpointError
from ..spec import MachineSpec
from ..surrogate.checkpoint import (
    checkpoint_dict,
    read_checkpoint,
    surrogate_from_dict,
    write_checkpoint_dict,
)
from ..surrogate.features import Normalization
from ..surrogate.model import Surrogate, build_net


def without_inputs(dataset: Dataset) -> Dataset:
    """``dataset`` without its exogenous inputs (:func:`narrow_episodes`), on its machine
    without inputs."""
    spec = replace(dataset.spec, inputs=())
    return Dataset(
        spec=spec,
        episodes={split: narrow_episodes(eps, spec) for split, eps in dataset.episodes.items()},
        root=dataset.root,
        manifest=dataset.manifest,
    )


def narrow_episodes(eps: Sequence[Episode], spec: MachineSpec) -> list[Episode]:
    """``eps`` on ``spec``, their machine without inputs: each episode's ``u`` keeps the
    joints' ``n_joint`` columns (views of the same arrays, not copies)."""
    return [e.replace(spec=spec, u=e.u[:, : spec.n_joint]) for e in eps]


def _insert(w: torch.Tensor, at: int, cols: torch.Tensor) -> torch.Tensor:
    """``w`` (..., n) with ``cols`` (..., k) inserted before its column ``at``."""
    return torch.cat([w[..., :at], cols, w[..., at:]], -1)


def _first_layer(net: torch.nn.Module) -> str:
    """The state-dict name of the weights that read the features (recurrent or ARX)."""
    return "linear.weight" if hasattr(net, "linear") else "rnn.weight_ih_l0"


def _resized(
    sur: Surrogate, state: dict[str, torch.Tensor], *, spec: MachineSpec, norm: Normalization
) -> Surrogate:
    """``sur`` on ``spec`` with the features of ``norm``: a network of its architecture
    with ``norm.n_feature`` inputs holding ``state``, built without drawing random numbers
    (the training's torch seed stays where it was)."""
    mcfg = replace(sur.model_cfg, n_feature=norm.n_feature)
    with torch.random.fork_rng(devices=[]):
        net = build_net(mcfg)
    net.load_state_dict(state)
    net = net.to(device=sur.device, dtype=sur.dtype).train(sur.net.training)
    return replace(sur, net=net, spec=spec, norm=norm, model_cfg=mcfg)


def _feature_weights(sur: Surrogate, state: dict[str, torch.Tensor]) -> tuple[str, torch.Tensor]:
    """The first layer's name and its weights as (rows, [window,] n_feature)."""
    name = _first_layer(sur.net)
    w = state[name]
    if name == "linear.weight":  # ARX: y = A vec(x_window), A's columns per (step, feature)
        w = w.reshape(len(w), sur.model_cfg.window, -1)
    return name, w


def widened(sur: Surrogate, *, spec: MachineSpec, like: Normalization) -> Surrogate:
    """``sur`` (trained without inputs) on the machine ``spec`` with its exogenous inputs:
    their feature columns are inserted with zero input weights, so the output is ``sur``'s
    up to the order of float sums.  They are normalised as in ``like``, the normalisation a
    network that uses them has (:meth:`.Normalization.fit` on the training data with them).

        W_ih = [W[:, :at], 0, W[:, at:]]
    """
    n_in, at = spec.n_input, sur.spec.n_feature
    state = {k: v.detach().clone() for k, v in sur.net.state_dict().items()}
    name, w = _feature_weights(sur, state)
    state[name] = _insert(w, at, w.new_zeros(*w.shape[:-1], n_in)).reshape(len(w), -1)
    if "prior.cols" in state:  # the static map reads command columns at or after ``at``
        cols = state["prior.cols"]
        state["prior.cols"] = cols + n_in * (cols >= at)
    n, cols = sur.norm, spec.input_features
    norm = replace(
        n,
        x_mean=_insert(n.x_mean, at, like.x_mean[cols].to(n.x_mean)),
        x_std=_insert(n.x_std, at, like.x_std[cols].to(n.x_std)),
        u_center=like.u_center.to(n.u_center),
        u_scale=like.u_scale.to(n.u_scale),
    )
    return _resized(sur, state, spec=replace(sur.spec, inputs=spec.inputs), norm=norm)


def narrowed(sur: Surrogate, *, where: str) -> Surrogate:
    """:func:`widened` undone: ``sur`` without its exogenous inputs' feature columns, whose
    input weights must be zero (a network trained to ignore them).

    Raises:
        CheckpointError: the network reads its inputs (trained with ``exogenous = "use"``).
    """
    spec = sur.spec
    cols, n_in = spec.input_features, spec.n_input
    state = {k: v.detach().clone() for k, v in sur.net.state_dict().items()}
    name, w = _feature_weights(sur, state)
    if bool(w[..., cols].any()):
        raise CheckpointError(
            f"{where}: the network reads its exogenous inputs {list(spec.u_names[spec.n_joint :])} "
            '(trained with exogenous = "use"); resume it with the same [train] exogenous'
        )
    state[name] = torch.cat([w[..., : cols.start], w[..., cols.stop :]], -1).reshape(len(w), -1)
    if "prior.cols" in state:
        c = state["prior.cols"]
        state["prior.cols"] = c - n_in * (c >= cols.stop)
    keep = [i for i in range(sur.norm.n_feature) if not cols.start <= i < cols.stop]
    n = sur.norm
    norm = replace(
        n,
        x_mean=n.x_mean[keep],
        x_std=n.x_std[keep],
        u_center=n.u_center[: spec.n_joint],
        u_scale=n.u_scale[: spec.n_joint],
    )
    return _resized(sur, state, spec=replace(spec, inputs=()), norm=norm)


def widen_checkpoint(path: Path, *, spec: MachineSpec, like: Normalization) -> None:
    """Rewrite the checkpoint at ``path`` (trained without inputs) :func:`widened` to
    ``spec`` and ``like``, atomically; its history and optimiser state are kept as they are."""
    ck = read_checkpoint(path)
    sur = widened(surrogate_from_dict(ck, where=str(path)), spec=spec, like=like)
    write_checkpoint_dict(
        path, checkpoint_dict(sur, history=ck.get("history"), train_state=ck.get("train_state"))
    )
