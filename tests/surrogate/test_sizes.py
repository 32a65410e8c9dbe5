"""Network sizes from the config alone, and the memory check before allocating."""

from __future__ import annotations

import pytest

from excavator_surrogate.errors import CheckpointError, ConfigError
from excavator_surrogate.surrogate.model import ModelConfig, build_net
from excavator_surrogate.surrogate.sizes import available_memory, check_fits, human_bytes, n_param


@pytest.mark.parametrize("cell", ["lstm", "gru", "arx"])
@pytest.mark.parametrize(("layers", "hidden", "head"), [(1, 5, 7), (2, 12, 8), (3, 4, 16)])
def test_n_param_counts_the_parameters_of_the_built_network(cell, layers, hidden, head):
    cfg = ModelConfig(
        n_feature=9, n_joint=3, hidden=hidden, n_layer=layers, cell=cell, head_hidden=head
    )
    assert n_param(cfg) == sum(p.numel() for p in build_net(cfg).parameters())


def test_check_fits_refuses_past_the_budget_in_one_line():
    check_fits(999, what="x", fix="y", available=1000)
    with pytest.raises(ConfigError) as e:
        check_fits(2_500_000_000, what="[train] hidden = 9", fix="lower it", available=10**9)
    assert str(e.value) == (
        "[train] hidden = 9 needs about 2.5 GB but 1 GB of memory is available: lower it"
    )
    with pytest.raises(CheckpointError):
        check_fits(2, what="a", fix="b", available=1, error=CheckpointError)


def test_available_memory_and_human_bytes():
    avail = available_memory()
    assert avail is None or avail > 0
    assert human_bytes(512) == "512 B" and human_bytes(1.5e18) == "1.5 EB"
