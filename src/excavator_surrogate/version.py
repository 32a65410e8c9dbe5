"""The package version: the one place it is written (pyproject.toml reads it through
``[tool.setuptools.dynamic]``; ``exsur --version`` prints it; the checkpoint records it)."""

__version__ = "0.1.0"
