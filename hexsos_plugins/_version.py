"""The version: the one place it is set (pyproject.toml reads it from here; a literal, so ``import
hexsos_plugins`` does not pay for importlib.metadata, 15 ms of every command's start)."""

__version__ = "0.1.0"
