"""derive: specialised, unrolled Python and C99 Kalman-family filters from SymPy models."""

from importlib.metadata import PackageNotFoundError, version

from .errors import ModelError
from .model import LinearModel, NonlinearModel

try:
    __version__ = version("derive")
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.1.0"

__all__ = ["LinearModel", "NonlinearModel", "ModelError", "__version__"]
