"""config.toml records and the commented config template: TOML written by tomli-w."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from excavator_surrogate.config import dumps_toml, toml_value

# Values the old hand-written writer turned into invalid TOML: a newline or tab in a string
# (a free-text note), a key that is not a bare word, a numpy float (repr "np.float64(...)").
AWKWARD = {
    "name": "run",
    "notes": {
        "why": ["first line\nsecond line", 'tab\there, "quoted", back\\slash'],
        "swing omega": 0.5,
        "a.b": {"deep": True},
    },
    "train": {
        "lr": np.float64(2e-3),
        "max_grad": math.inf,
        "dims": (2, 128),
        "hydraulics": {"delay": [0.02, 0.05], "empty": {}},
    },
}


def test_dumps_toml_round_trips_awkward_values() -> None:
    back = tomllib.loads(dumps_toml(AWKWARD))
    assert back["notes"] == AWKWARD["notes"]
    assert back["train"]["lr"] == pytest.approx(2e-3, rel=0, abs=0)
    assert back["train"]["max_grad"] == math.inf
    assert back["train"]["dims"] == [2, 128]
    assert back["train"]["hydraulics"] == {"delay": [0.02, 0.05], "empty": {}}
    assert back["name"] == "run"


def test_dumps_toml_rejects_none() -> None:
    with pytest.raises(TypeError):
        dumps_toml({"train": {"lr": None}})


@pytest.mark.parametrize(
    "value",
    [
        AWKWARD["notes"],
        AWKWARD["train"]["hydraulics"],
        [[1, 2], {"k": "v\n"}, -0.0, 1e-300],
        "line\nbreak",
        True,
    ],
)
def test_toml_value_is_one_loadable_line(value: object) -> None:
    text = toml_value(value)
    assert "\n" not in text
    assert tomllib.loads(f"v = {text}")["v"] == tomllib.loads(dumps_toml({"v": value}))["v"]
