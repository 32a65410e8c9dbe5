"""The per-member LSTM kernel's layout, its block check and the finest blocks of a merge."""

from __future__ import annotations

import torch

from excavator_surrogate.surrogate.member_lstm import (
    MemberLSTM,
    from_dense,
    member_count,
    to_dense,
)


def test_layout_round_trip() -> None:
    h = torch.randn(2, 5, 12)
    m = from_dense(h, 3)
    assert m.shape == (2, 3, 5, 4)
    torch.testing.assert_close(to_dense(m), h)
    torch.testing.assert_close(m[:, 1], h[:, :, 4:8])


def test_from_layers_rejects_weights_off_the_blocks() -> None:
    m, h, n_in = 2, 3, 5
    w_ih = torch.zeros(4 * m * h, n_in) + 0.1
    w_hh = torch.zeros(4 * m * h, m * h)
    b = torch.zeros(4 * m * h)
    assert MemberLSTM.from_layers([(w_ih, w_hh, b, b)], m) is not None
    w_hh[0, m * h - 1] = 1.0  # member 0's input-gate row reads member 1's state
    assert MemberLSTM.from_layers([(w_ih, w_hh, b, b)], m) is None
    assert MemberLSTM.from_layers([(w_ih, torch.zeros(4 * 5, 5), b, b)], 2) is None  # 5 % 2


def _layers(widths: list[int], *, n_in: int = 5, n_layer: int = 2, seed: int = 0):
    """Per layer ``(w_ih, w_hh, b_ih, b_hh)`` of an LSTM whose units form diagonal blocks of
    ``widths`` (random weights inside the blocks, zeros outside), gates in PyTorch's order."""
    gen = torch.Generator().manual_seed(seed)
    big = sum(widths)
    mask = torch.block_diag(*[torch.ones(w, w) for w in widths])  # (H, H)
    layers = []
    for k in range(n_layer):
        w_hh = torch.randn(4, big, big, generator=gen) * mask
        w_ih = (
            torch.randn(4, big, n_in, generator=gen)
            if k == 0
            else torch.randn(4, big, big, generator=gen) * mask
        )
        b = torch.randn(4 * big, generator=gen)
        layers.append((w_ih.reshape(4 * big, -1), w_hh.reshape(4 * big, big), b, b))
    return layers


def test_member_count_finds_the_finest_equal_blocks() -> None:
    assert member_count(_layers([4, 4, 4])) == 3
    assert member_count(_layers([4] * 6)) == 6
    assert member_count(_layers([12])) is None  # one block: a single network
    assert member_count(_layers([4, 5])) is None  # blocks of different widths
    layers = _layers([4, 4, 4])
    w_ih, w_hh, b, _ = layers[1]
    w_hh = w_hh.clone()
    w_hh[4 * 12 - 1, 0] = 0.5  # a deeper layer's output gate of unit 11 reads unit 0
    assert member_count([layers[0], (w_ih, w_hh, b, b)]) is None
    w_ih = w_ih.clone()
    w_ih[5, 0] = 0.5  # layer 1's unit 5 reads layer 0's unit 0: blocks 0 and 1 join
    assert member_count([layers[0], (w_ih, layers[1][1], b, b)]) is None  # widths 8 and 4
