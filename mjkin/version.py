"""mjkin's version: the one place it is written (pyproject.toml reads it; nothing here imports the package)."""

__version__ = "0.1.0"
