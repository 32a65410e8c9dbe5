"""The package version (one place; the checkpoint records it)."""

__version__ = "0.1.0"
