"""derive: specialised, unrolled Python and C99 Kalman-family filters from SymPy models."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("derive")
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.1.0"

from . import catalog  # noqa: E402
from .build import build_c, load_python  # noqa: E402
from .errors import ModelError  # noqa: E402
from .generation import generate  # noqa: E402
from .model import LinearModel, NonlinearModel  # noqa: E402
from .pipeline import load_generated  # noqa: E402

__all__ = ["LinearModel", "ModelError", "NonlinearModel", "__version__", "build_c", "catalog",
           "generate", "load_generated", "load_python"]
