"""Fixtures: tiny synthetic machines and episodes (tests.helpers.fixtures)."""

from tests.helpers.fixtures import episodes, rng, spec

__all__ = ["episodes", "rng", "spec"]
