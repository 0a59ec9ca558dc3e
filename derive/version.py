"""The version of derive, for the package and for the headers of generated files.

Its own module, with no imports from derive, so that the generator (derive.emit) can
name the version without importing the package's public API (derive/__init__.py).
"""

from importlib.metadata import PackageNotFoundError, version

DISTRIBUTION = "derive-filters"
"""The name derive is installed under (``pip install derive-filters``); the name ``derive``
on the package index belongs to another project. The import name and the command stay
``derive``."""

try:
    __version__ = version(DISTRIBUTION)
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.1.0"
