"""merge refuses a member with non-finite weights and the same member twice."""

from __future__ import annotations

import pytest
import torch

from excavator_surrogate.errors import ConfigError
from excavator_surrogate.surrogate.ensemble import merge, non_finite_weight
from tests.helpers.surrogates import make_surrogate


def test_merge_refuses_a_member_with_nan_weights(spec, episodes):
    a = make_surrogate(spec, episodes, seed=0, window=5)
    b = make_surrogate(spec, episodes, seed=1, window=5)
    assert non_finite_weight(b) is None
    with torch.no_grad():
        b.net.head[2].weight[0, 0] = float("nan")
    assert non_finite_weight(b) == "head.2.weight"
    with pytest.raises(
        ConfigError, match=r"member 1 \(.*\) has non-finite weights \(head.2.weight\)"
    ):
        merge([a, b])


def test_merge_refuses_the_same_member_twice(spec, episodes):
    a = make_surrogate(spec, episodes, seed=0, window=5)
    b = make_surrogate(spec, episodes, seed=1, window=5)
    with pytest.raises(ConfigError, match="member 2 .* has the same weights as ensemble member 0"):
        merge([a, b, a])
    assert merge([a, b]).metrics["ensemble"]["n_member"] == 2
