"""A merged seed ensemble's free run stepped member by member: :func:`split`.

:func:`.ensemble.merge` makes M members one network whose hidden state is the members'
states side by side, so its recurrent, deeper-layer and first head matrices are
block-diagonal: of the ``4 H x H`` products of a merged LSTM layer's recurrent matrix
(``H = M h``), only the M diagonal ``4 h x h`` blocks are not zero.  Stepped one sample at a
time at a small batch, a step mostly reads those matrices (``4 H x H`` float32 is 9 MB at
M = 6, h = 128), so the zeros cost M times the memory traffic and the arithmetic that the
members need.  The choices after training (static map, network kind) and the scoring of a
recipe free-run such ensembles on whole splits, sample by sample.

:class:`BlockNet` steps the same network as its M member blocks
(:class:`~.member_lstm.MemberLSTM`, one batched product per layer over the members), then
the head per member block::

    gates_m = b_m + x_m W_ih,m + h_m W_hh,m                        (M, n, 4 h), baddbmm
    c_m <- sigmoid(f) c_m + sigmoid(i) tanh(g);  h_m <- sigmoid(o) tanh(c_m)
    a_m = relu(b1_m + h_m W1_m)                                   (M, n, f), baddbmm
    y = b2 + [a_1, ..., a_M] W2  (+ velocity feature if residual, + prior if prior)

where layer 0's ``x_m`` is the shared input and a deeper layer's is member m's output of
the layer below; the ReLU is the merged head's own module, run on the merged layout
``[a_1, ..., a_M]``, so the member reports of :class:`~.ensemble.MemberHead` read it as
they read the merged network's.  These are the merged network's products without the
zeros, summed in another order: the results agree with the merged network's to float32
rounding, not bit for bit (tested against it and against the members averaged in a plain
loop).  The warm-up (:meth:`BlockNet.forward_seq`) runs the merged network's own recurrent
module.

Splitting starts at two members of 128 units (:data:`MIN_SPLIT_WIDTH`: level at batch 2,
faster from there on): a narrower merged network is fast already, and the member kernel's
dozen small operations a layer cost about what its zeros do (``python bench/blocks.py``).
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import nn

from .member_lstm import MemberLSTM, from_dense, member_count, to_dense
from .model import CELL_WEIGHTS, State, Surrogate, SurrogateNet

MIN_SPLIT_WIDTH = 256
"""Merged recurrent widths ``H = M h`` from which :func:`split` steps the members.  A whole
free-run step (``bench/blocks.py``, one thread, batch 2 / 13, an AVX-512 computer, medians of
paired runs) takes 0.99 / 0.79x the merged network's time for two members of 128 units,
0.85 / 0.34x for four and 0.73 / 0.25x for six; two and three members of 64 are level
(0.97-1.03x)."""


def worth_splitting(sur: Surrogate) -> bool:
    """Whether ``sur``'s merged width is at least :data:`MIN_SPLIT_WIDTH`."""
    return int(getattr(sur.model_cfg, "hidden", 0)) >= MIN_SPLIT_WIDTH


def _layers(net: SurrogateNet) -> list[tuple[torch.Tensor, ...]]:
    """Per layer ``(w_ih, w_hh, b_ih, b_hh)`` of ``net``'s recurrent module, detached."""
    return [
        tuple(getattr(net.rnn, f"{w}_l{k}").detach() for w in CELL_WEIGHTS)
        for k in range(net.cfg.n_layer)
    ]


class BlockNet(nn.Module):
    """A merged LSTM network stepped as its M member blocks (see the module docstring): the
    stateful interface of a :class:`~.model.SurrogateNet` (``init_state``, ``forward_seq``,
    ``step``).  Its state is the member kernel's member-major ``(n_layer, M, n_batch, h)``
    (:func:`~.member_lstm.from_dense` of the merged network's).

    Build it with :meth:`of`, which returns None when the weights are not M equal blocks.
    The blocks are copied when it is built; it does not follow later training.
    """

    stateful_capable = True

    def __init__(self, net: SurrogateNet, kernel: MemberLSTM) -> None:
        super().__init__()
        self.cfg = net.cfg
        self._net = (net,)  # a tuple: not registered as a submodule
        self.kernel = kernel
        m, h = kernel.n_member, kernel.width
        w1, b1 = net.head[0].weight.detach(), net.head[0].bias.detach()
        f = w1.shape[0] // m
        # W1_m^T (M, h, f): member m's head units read its own recurrent units only
        self._w1 = (
            torch.stack([w1[i * f : (i + 1) * f, i * h : (i + 1) * h] for i in range(m)])
            .transpose(1, 2)
            .contiguous()
        )
        self._b1 = b1.reshape(m, 1, f).contiguous()
        # W2^T (M f, n_joint): the merged output layer as it is
        self._w2 = net.head[2].weight.detach().t().contiguous()
        self._b2 = net.head[2].bias.detach().clone()
        # the merged head's ReLU and speed prior (tuples: not registered as submodules)
        self._act, self._prior = (net.head[1],), (net.prior,)
        # a parameter only so that the surrogate knows its device and dtype
        self._like = nn.Parameter(self._b2.new_zeros(()), requires_grad=False)

    @classmethod
    def of(cls, net: SurrogateNet) -> BlockNet | None:
        """The member-by-member form of ``net``, or None: not an LSTM, one block, blocks of
        different widths, or a head that mixes the blocks."""
        if not isinstance(net, SurrogateNet) or net.cfg.cell != "lstm":
            return None
        layers = _layers(net)
        n_member = member_count(layers)
        kernel = None if n_member is None else MemberLSTM.from_layers(layers, n_member)
        if kernel is None or net.cfg.head_hidden % kernel.n_member:
            return None
        m, h, f = kernel.n_member, kernel.width, net.cfg.head_hidden // kernel.n_member
        blocks = torch.block_diag(*[torch.ones(f, h, dtype=torch.bool)] * m)
        if bool((net.head[0].weight.detach()[~blocks.to(net.head[0].weight.device)] != 0).any()):
            return None
        return cls(net, kernel)

    @property
    def n_member(self) -> int:
        """M, the member blocks stepped."""
        return self.kernel.n_member

    def init_state(self, n_batch: int) -> State:
        """Zero state ``(h, c)``, each ``(n_layer, M, n_batch, h)``."""
        h, c = self._net[0].init_state(n_batch)
        return from_dense(h, self.n_member), from_dense(c, self.n_member)

    def forward_seq(
        self, x: torch.Tensor, state: State | None = None
    ) -> tuple[torch.Tensor, State]:
        """The merged network's own :meth:`~.model.SurrogateNet.forward_seq` (the warm-up),
        on and to the member-major state."""
        net, m = self._net[0], self.n_member
        dense = None if state is None else (to_dense(state[0]), to_dense(state[1]))
        y, (h, c) = net.forward_seq(x, dense)
        return y, (from_dense(h, m), from_dense(c, m))

    @property
    def head(self) -> nn.Sequential:
        """The merged network's head (FC, ReLU, linear): its ReLU module runs in every
        :meth:`step`, on the merged layout, so a hook on it (:class:`~.ensemble.MemberHead`)
        sees what it sees on the merged network."""
        return self._net[0].head

    @property
    def prior(self) -> nn.Module | None:
        """The merged network's speed prior, or None."""
        return self._net[0].prior

    def step(self, x_t: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        """``x_t: (n_batch, n_feature)`` -> ``(n_batch, n_joint)`` and the new ``(h, c)``."""
        _, h, c = self.kernel.step(x_t, *state)
        n = x_t.shape[0]
        # a = relu([b1_m + h_m W1_m]_m), member-major (M, n, f) to the merged (n, M f)
        pre = torch.baddbmm(self._b1, h[-1], self._w1)
        a = self._act[0](pre.transpose(0, 1).reshape(n, -1))
        # y = b2 + a W2                                                     (n, n_joint)
        y = torch.addmm(self._b2, a, self._w2)
        if self.cfg.residual:
            y = y + x_t[..., -self.cfg.n_joint :]
        if self._prior[0] is not None:
            y = y + self._prior[0](x_t)
        return y, (h, c)


def split(sur: Surrogate) -> Surrogate:
    """``sur`` with its merged network stepped member by member (:class:`BlockNet`), or
    ``sur`` itself: not stateful, narrower than :data:`MIN_SPLIT_WIDTH`, not a merged
    LSTM of equal blocks, or without a merge record (``metrics`` ``ensemble`` /
    ``composite``).

    The returned surrogate shares ``sur``'s spec, normalisation and metrics, and runs in a
    :class:`~.rollout.ClosedLoop` with or without member reports.
    """
    metrics = sur.metrics or {}
    merged = isinstance(metrics.get("ensemble") or metrics.get("composite"), dict)
    if not merged or sur.mode != "stateful" or not worth_splitting(sur):
        return sur
    block = BlockNet.of(sur.net)  # type: ignore[arg-type]
    if block is None:
        return sur
    sur.net.eval()
    return replace(sur, net=block)
