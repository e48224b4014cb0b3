"""The package version, as the binding reports it (one home, so no module imports the package
``__init__`` for it)."""

from ._core import __version__

__all__ = ["__version__"]
