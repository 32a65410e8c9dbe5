"""Per-member LSTM kernel for merged seed ensembles: :class:`MemberLSTM`.

A merged ensemble (:func:`~excavator_surrogate.surrogate.ensemble.merge`) is one LSTM whose
weights are block-diagonal: member ``m`` owns rows ``[m H, (m + 1) H)`` of every gate block
and, from layer 1 on and in every recurrent matrix, only the matching columns.  The dense
kernels multiply all the zero blocks too: with ``M`` members that is ``M`` times the useful
work of the recurrent products.  :class:`MemberLSTM` cuts the blocks back out and steps the
members as one batched matmul (``torch.baddbmm`` over the member axis): for two members of
width 64 at 256 envs on one core, a whole engine step takes 1.04 ms against the dense cell's
1.42 (1.36x).

It steps the environments' engine (``SurrogateEngine(impl="members")``) and the batched free
runs (:mod:`.blocks`).  :func:`member_count` finds the finest equal blocks in the weights, so
a merge of merges (the kind choice's ensemble of composites) steps as its smallest members.

State layout: ``h``, ``c`` (n_layer, M, n_envs, H), member-major, so no step copies it.
:func:`to_dense` / :func:`from_dense` convert to and from the dense ``(n_layer, n_envs, M H)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

_ORDER = (0, 1, 3, 2)
"""PyTorch's gate blocks are (input, forget, cell, output); the member kernel stores them as
(input, forget, output, cell) so that one sigmoid covers the first three."""


class MemberLSTM:
    """The members' blocks of a merged LSTM's (folded) layer weights.

    Args:
        layers: per layer ``(w_ih, w_hh, b_ih, b_hh)`` of the merged LSTM, ``w_ih``
            (4 M H, n_in), ``w_hh`` (4 M H, M H).
        n_member: M.

    Use :meth:`from_layers`, which returns ``None`` when the weights are not exactly
    block-diagonal with M equal blocks (the dense kernels then apply).
    """

    def __init__(self, layers: Sequence[tuple[torch.Tensor, ...]], n_member: int) -> None:
        m = int(n_member)
        hidden = layers[0][1].shape[1]
        self.n_member = m
        self.width = h = hidden // m
        self.weights: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        rows = [_rows(i, h, m) for i in range(m)]  # gates in _ORDER
        for k, (w_ih, w_hh, b_ih, b_hh) in enumerate(layers):
            # member i: W_ih,i (n_in_i, 4H), W_hh,i (H, 4H), b_i (1, 4H), transposed for x @ W
            wi = torch.stack(
                [w_ih[r] if k == 0 else w_ih[r][:, i * h : (i + 1) * h] for i, r in enumerate(rows)]
            ).transpose(1, 2)
            wh = torch.stack([w_hh[r][:, i * h : (i + 1) * h] for i, r in enumerate(rows)])
            b = torch.stack([(b_ih + b_hh)[r] for r in rows]).unsqueeze(1)
            self.weights.append((wi.contiguous(), wh.transpose(1, 2).contiguous(), b))

    @classmethod
    def from_layers(
        cls, layers: Sequence[tuple[torch.Tensor, ...]], n_member: int
    ) -> MemberLSTM | None:
        """The member kernel, or ``None`` unless the merged weights are exactly M equal
        diagonal blocks (everything off the blocks is zero)."""
        m = int(n_member)
        hidden = layers[0][1].shape[1]
        if m < 2 or hidden % m:
            return None
        h = hidden // m
        # off the blocks: True everywhere except member i's rows x member i's columns
        off = torch.ones(4 * hidden, hidden, dtype=torch.bool)
        for i in range(m):
            off[_rows(i, h, m).unsqueeze(1), torch.arange(i * h, (i + 1) * h)] = False
        for k, (w_ih, w_hh, _, _) in enumerate(layers):
            mats = [w_hh] if k == 0 else [w_ih, w_hh]
            if any(torch.count_nonzero(w[off.to(w.device)]) for w in mats):
                return None
        return cls(layers, m)

    def step(
        self, x: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One sample: ``x`` (n_envs, n_raw), ``h``, ``c`` (n_layer, M, n_envs, H).

        Returns the last layer's output as the dense (n_envs, M H) and the new ``h``, ``c``.
        """
        inp = x.unsqueeze(0).expand(self.n_member, -1, -1)
        h_new, c_new = torch.empty_like(h), torch.empty_like(c)
        w = self.width
        for k, (wi, wh, b) in enumerate(self.weights):
            # gates = b + x W_ih,m + h W_hh,m per member m: (M, n_envs, 4H), order i f o g
            g = torch.baddbmm(b, inp, wi).baddbmm_(h[k], wh)
            s = torch.sigmoid(g[..., : 3 * w])
            i, f, o = s[..., :w], s[..., w : 2 * w], s[..., 2 * w :]
            # c' = σ(f) ⊙ c + σ(i) ⊙ tanh(g);  h' = σ(o) ⊙ tanh(c')
            c_k = torch.addcmul(f * c[k], i, torch.tanh(g[..., 3 * w :]), out=c_new[k])
            inp = torch.mul(o, torch.tanh(c_k), out=h_new[k])
        return to_dense(inp), h_new, c_new


def member_count(layers: Sequence[tuple[torch.Tensor, ...]]) -> int | None:
    """The number M >= 2 of the finest equal diagonal blocks of a merged LSTM's layers (per
    layer ``(w_ih, w_hh, b_ih, b_hh)``): no recurrent or deeper-layer weight links two
    blocks.  None: one block (a single network), or blocks of different widths."""
    hidden = layers[0][1].shape[1]
    # links[i, j]: unit j's output feeds unit i's gates in some layer (or the reverse) (H, H)
    links = torch.zeros(hidden, hidden, dtype=torch.bool)
    for k, (w_ih, w_hh, _, _) in enumerate(layers):
        for w in [w_hh] if k == 0 else [w_ih, w_hh]:
            links |= (w.detach().reshape(4, hidden, hidden) != 0).any(0).cpu()
    links |= links.T.clone()
    idx = torch.arange(hidden)
    # a block may end after unit b iff no unit up to b links a unit after b
    last = torch.where(links, idx[None, :], -1).amax(1)  # last unit that unit i links
    reach = torch.cummax(torch.maximum(last, idx), 0).values
    ends = (idx[reach == idx] + 1).tolist()
    widths = {b - a for a, b in zip([0, *ends[:-1]], ends)}
    if len(ends) < 2 or len(widths) != 1:
        return None
    return len(ends)


def _rows(i: int, h: int, m: int) -> torch.Tensor:
    """Row indices of member ``i`` in the 4 gate blocks of a merged (4 M h)-row matrix."""
    return torch.cat([torch.arange(g * m * h + i * h, g * m * h + (i + 1) * h) for g in _ORDER])


def to_dense(h: torch.Tensor) -> torch.Tensor:
    """Member-major ``(..., M, n_envs, H)`` to the dense ``(..., n_envs, M H)``."""
    *lead, m, n, w = h.shape
    return h.transpose(-3, -2).reshape(*lead, n, m * w)


def from_dense(h: torch.Tensor, n_member: int) -> torch.Tensor:
    """The dense ``(..., n_envs, M H)`` to member-major ``(..., M, n_envs, H)``."""
    *lead, n, hidden = h.shape
    return h.reshape(*lead, n, n_member, hidden // n_member).transpose(-3, -2).contiguous()
