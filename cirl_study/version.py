"""The package's version, and its one source: ``pyproject.toml`` reads it from here, so no
command's start-up reads the installed metadata for it."""

__version__ = "0.1.0"
