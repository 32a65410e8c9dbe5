"""Several networks' free runs in one batched loop: :func:`stack`.

Training validates two candidates every epoch (the raw weights and their moving average) by
a free run of the whole validation split.  One sample through a 2 x 128 LSTM is small, so a
free-run step costs mostly the dispatch of its few dozen small operations, not arithmetic,
and two separate free runs cost twice that.  :func:`stack` makes C LSTM networks of one
architecture one :class:`StackedNet` that a single :class:`~.rollout.ClosedLoop` steps: the
loop's batch holds every candidate's copy of the episodes, candidate-major (rows
``c * n ... (c + 1) * n - 1`` are candidate ``c``'s), each row feeds back its own
candidate's angle, and the features and angles of all candidates are computed together.
One step runs every candidate's cells as one batched matrix product per layer::

    gates_c = [x_c, h_c] @ [W_ih,c ; W_hh,c]^T + b_ih,c + b_hh,c     (C, n, 4 hidden), bmm
    i, f, g, o = sigmoid, sigmoid, tanh, sigmoid of the four blocks of gates_c
    c_c <- f * c_c + i * g;   h_c <- o * tanh(c_c)
    y_c = W2_c relu(W1_c h_c + b1_c) + b2_c  (+ x_c's velocity feature if residual)
                                            (+ prior_c(x_c) if prior)

The same maths as C separate runs (``torch.lstm_cell``), summed in another order, so the
results agree to float32 rounding, not bit for bit (tested against the per-candidate runs).
The warm-up runs each candidate's own recurrent module on its rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import nn

from .model import State, Surrogate, SurrogateNet


def stackable(surs: Sequence[Surrogate]) -> bool:
    """Whether ``surs`` can run as one :class:`StackedNet`: stateful LSTM networks with the
    same architecture, device, dtype, machine spec, end stops and normalisation (the loop
    encodes features and integrates angles once for all of them)."""
    if len(surs) < 2:
        return False
    ref = surs[0]
    if not isinstance(ref.net, SurrogateNet) or ref.model_cfg.cell != "lstm":
        return False
    if ref.mode != "stateful":
        return False
    norm0 = ref.norm.state_dict()
    for s in surs[1:]:
        if not isinstance(s.net, SurrogateNet) or s.model_cfg != ref.model_cfg:
            return False
        if (s.mode, s.end_stops, s.device, s.dtype) != (
            ref.mode,
            ref.end_stops,
            ref.device,
            ref.dtype,
        ):
            return False
        if s.spec.to_dict() != ref.spec.to_dict():
            return False
        if s.norm is not ref.norm:
            norm = s.norm.state_dict()
            if norm.keys() != norm0.keys() or not all(
                torch.equal(torch.as_tensor(norm[k]), torch.as_tensor(norm0[k])) for k in norm
            ):
                return False
    return True


class StackedNet(nn.Module):
    """C stateful LSTM :class:`~.model.SurrogateNet` s of one architecture as one network over
    candidate-major rows (see the module docstring): the interface of a ``SurrogateNet``
    (``init_state``, ``forward_seq``, ``step``) for ``n_batch = C * n``, with the state
    ``(h, c)`` of each ``(n_layer, C * n, hidden)`` as the candidates' own side by side.

    The candidates' weights are copied when it is built; it does not follow later training.
    """

    stateful_capable = True

    def __init__(self, nets: Sequence[SurrogateNet]) -> None:
        super().__init__()
        self.n_cand = len(nets)
        self.cfg = nets[0].cfg
        self._nets = tuple(nets)  # a tuple: not registered as submodules
        with torch.no_grad():
            # per layer: W (C, n_in + hidden, 4 hidden) = [W_ih ; W_hh]^T, b (C, 1, 4 hidden)
            w, b = [], []
            for k in range(self.cfg.n_layer):
                ws = [
                    torch.cat(
                        [getattr(n.rnn, f"weight_ih_l{k}"), getattr(n.rnn, f"weight_hh_l{k}")], 1
                    )
                    for n in nets
                ]
                bs = [
                    getattr(n.rnn, f"bias_ih_l{k}") + getattr(n.rnn, f"bias_hh_l{k}") for n in nets
                ]
                w.append(torch.stack(ws).transpose(1, 2).contiguous())
                b.append(torch.stack(bs).unsqueeze(1))
            # head: (C, hidden, head_hidden), (C, head_hidden, n_joint) and their biases
            for i in (0, 2):
                w.append(torch.stack([n.head[i].weight for n in nets]).transpose(1, 2).contiguous())
                b.append(torch.stack([n.head[i].bias for n in nets]).unsqueeze(1))
        # copies, not trained (parameters only so that the surrogate knows its device and dtype)
        self.weights = nn.ParameterList([nn.Parameter(t, requires_grad=False) for t in w + b])
        n = len(w)
        self._w, self._b = list(self.weights[:n]), list(self.weights[n:])  # plain lists: fast
        # candidates of one training (raw and averaged weights) share its fitted map: one
        # call on every row instead of one per candidate (the map is elementwise per row)
        maps = [net.prior.state_dict() for net in nets] if self.cfg.prior else []
        self._one_prior = bool(maps) and all(
            all(torch.equal(m[k], maps[0][k]) for k in maps[0]) for m in maps[1:]
        )

    def _extras(self, y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """``y`` plus each candidate's residual / prior terms (:meth:`SurrogateNet._out`) on its
        own rows of ``x: (C * n, n_feature)``."""
        if self.cfg.residual:
            y = y + x[..., -self.cfg.n_joint :]
        if self._one_prior:
            y = y + self._nets[0].prior(x)
        elif self.cfg.prior:
            y = torch.cat(
                [
                    y_c + net.prior(x_c)
                    for y_c, x_c, net in zip(y.chunk(self.n_cand), x.chunk(self.n_cand), self._nets)
                ]
            )
        return y

    def init_state(self, n_batch: int) -> State:
        """Zero state ``(h, c)``, each ``(n_layer, n_batch, hidden)``."""
        return self._nets[0].init_state(n_batch)

    def forward_seq(
        self, x: torch.Tensor, state: State | None = None
    ) -> tuple[torch.Tensor, State]:
        """``x: (C * n, n_step, n_feature)`` -> ``(C * n, n_step, n_joint)`` and the state: each
        candidate's own :meth:`SurrogateNet.forward_seq` on its rows."""
        if state is None:
            state = self.init_state(x.shape[0])
        h, c = (s.chunk(self.n_cand, dim=1) for s in state)
        ys, hs, cs = [], [], []
        for k, (net, x_c) in enumerate(zip(self._nets, x.chunk(self.n_cand), strict=True)):
            y_c, (h_c, c_c) = net.forward_seq(x_c, (h[k], c[k]))
            ys.append(y_c)
            hs.append(h_c)
            cs.append(c_c)
        return torch.cat(ys), (torch.cat(hs, dim=1), torch.cat(cs, dim=1))

    def step(self, x_t: torch.Tensor, state: State) -> tuple[torch.Tensor, State]:
        """``x_t: (C * n, n_feature)`` -> ``(C * n, n_joint)`` and the new state."""
        n_cand, hid = self.n_cand, self.cfg.hidden
        h, c = state
        inp = x_t.reshape(n_cand, -1, x_t.shape[-1])
        hs, cs = [], []
        for k in range(self.cfg.n_layer):
            h_k = h[k].reshape(n_cand, -1, hid)
            # gates = [x, h] W^T + b                                          (C, n, 4 hidden)
            gates = torch.baddbmm(self._b[k], torch.cat([inp, h_k], dim=-1), self._w[k])
            i, f, g, o = gates.chunk(4, dim=-1)
            # c <- sigmoid(f) c + sigmoid(i) tanh(g);  h <- sigmoid(o) tanh(c)
            c_prev = c[k].reshape(n_cand, -1, hid)
            c_k = torch.sigmoid(f) * c_prev + torch.sigmoid(i) * torch.tanh(g)
            inp = torch.sigmoid(o) * torch.tanh(c_k)
            hs.append(inp.reshape(-1, hid))
            cs.append(c_k.reshape(-1, hid))
        n_layer = self.cfg.n_layer
        (w1, w2), (b1, b2) = self._w[n_layer:], self._b[n_layer:]
        # y = W2 relu(W1 h + b1) + b2                                       (C, n, n_joint)
        y = torch.baddbmm(b2, torch.relu(torch.baddbmm(b1, inp, w1)), w2)
        return self._extras(y.reshape(-1, y.shape[-1]), x_t), (torch.stack(hs), torch.stack(cs))


def stack(surs: Sequence[Surrogate]) -> Surrogate:
    """The candidates ``surs`` (:func:`stackable`) as one surrogate over candidate-major rows:
    roll it out on ``len(surs)`` copies of the episodes, candidate after candidate.

    Raises:
        ValueError: ``surs`` are not :func:`stackable`.
    """
    if not stackable(surs):
        raise ValueError("these surrogates differ in more than their weights: run them one by one")
    for s in surs:
        s.net.eval()
    return replace(surs[0], net=StackedNet([s.net for s in surs]))
