"""SurrogateNet: the fused one-step cell path equals the sequence module (values and gradients)."""

from __future__ import annotations

import pytest
import torch

from excavator_surrogate.surrogate.model import ModelConfig, SurrogateNet

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("cell", ["lstm", "gru"])
def test_step_equals_forward_seq(cell: str, device: str) -> None:
    torch.manual_seed(0)
    net = SurrogateNet(ModelConfig(n_feature=7, n_joint=3, hidden=16, head_hidden=8, cell=cell))
    net = net.to(device)
    x = torch.randn(5, 12, 7, device=device)
    state0 = tuple(s + 0.1 * torch.randn_like(s) for s in net.init_state(5))

    y_seq, (h_seq, c_seq) = net.forward_seq(x, state0)
    (y_seq.square().sum() + h_seq.sum()).backward()
    g_seq = [p.grad.clone() for p in net.parameters()]
    net.zero_grad()

    state, ys = state0, []
    for k in range(x.shape[1]):  # plain loop of the fused cell step
        y, state = net.step(x[:, k], state)
        ys.append(y)
    y_step = torch.stack(ys, dim=1)
    (y_step.square().sum() + state[0].sum()).backward()
    g_step = [p.grad.clone() for p in net.parameters()]

    torch.testing.assert_close(y_step, y_seq, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(state[0], h_seq, atol=1e-5, rtol=1e-5)
    if cell == "lstm":
        torch.testing.assert_close(state[1], c_seq, atol=1e-5, rtol=1e-5)
    for a, b in zip(g_step, g_seq):
        torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize("cell", ["lstm", "gru"])
def test_step_reads_the_same_weights_from_the_flat_list_as_by_name(cell: str) -> None:
    """step() takes the cells' weights from the module's flat list; looked up by name (the
    path for another torch layout) they are the same tensors, so the outputs are equal to the
    bit, also after a dtype change and after a weight is replaced."""
    torch.manual_seed(0)
    net = SurrogateNet(ModelConfig(n_feature=7, n_joint=3, hidden=16, head_hidden=8, cell=cell))
    assert net._flat_layout
    x = torch.randn(4, 7)
    state = tuple(0.1 * torch.randn_like(s) for s in net.init_state(4))

    def both() -> torch.Tensor:
        fast, _ = net.step(x, state)
        net._flat_layout = False
        try:
            named, _ = net.step(x, state)
        finally:
            net._flat_layout = True
        assert torch.equal(fast, named)
        return fast

    before = both()
    net = net.double()
    x, state = x.double(), tuple(s.double() for s in state)
    assert both().dtype == torch.float64
    with torch.no_grad():
        net.rnn.weight_ih_l0 = torch.nn.Parameter(2.0 * net.rnn.weight_ih_l0)
    assert not torch.equal(both().float(), before)  # the replaced weight is read
