"""The package's version, from its installed metadata (``pyproject.toml``'s ``version``)."""

from importlib import metadata

try:
    __version__ = metadata.version("factirl-opt")
except metadata.PackageNotFoundError:  # imported from a source tree that was never installed
    __version__ = "0+unknown"
