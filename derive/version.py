"""The version of derive, for the package and for the headers of generated files.

Its own module, with no imports from derive, so that the generator (derive.emit) can
name the version without importing the package's public API (derive/__init__.py).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("derive")
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.1.0"
