"""``RLConfig``'s PPO budget: the env-steps trained and the learning-curve schedule."""

from __future__ import annotations

import pytest

from excavator_surrogate.control.rl import RLConfig


@pytest.mark.parametrize(
    ("kw", "steps"),
    [
        ({}, 999_424),  # 244 updates of 128 x 32: the report said 1000000
        ({"n_envs": 4, "total_steps": 255}, 128),  # said 255
        ({"n_envs": 2, "total_steps": 128}, 128),
    ],
)
def test_train_steps_are_whole_ppo_updates(kw: dict, steps: int) -> None:
    assert RLConfig(**kw).train_steps == steps


@pytest.mark.parametrize(
    ("kw", "updates"),
    [
        # 15 updates, 8 points: there were 15 (every update), one per n_update // n_curve = 1
        ({"n_envs": 1, "total_steps": 15 * 32}, [2, 4, 6, 8, 9, 11, 13, 15]),
        ({}, [31, 61, 92, 122, 153, 183, 214, 244]),  # the default: the last at the last update
        ({"n_envs": 1, "total_steps": 3 * 32}, [1, 2, 3]),  # fewer updates than points
        ({"n_envs": 1, "total_steps": 32, "n_curve": 1}, [1]),
    ],
)
def test_the_curve_has_n_curve_points_over_the_updates(kw: dict, updates: list[int]) -> None:
    assert RLConfig(**kw).curve_updates() == updates
