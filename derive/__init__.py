"""derive: specialised, unrolled Python and C99 Kalman-family filters from SymPy models."""

from . import catalog
from .build import build_c, load_python
from .errors import ModelError
from .generation import generate
from .model import LinearModel, NonlinearModel, Sensor
from .pipeline import load_generated
from .version import __version__

__all__ = ["LinearModel", "ModelError", "NonlinearModel", "Sensor", "__version__", "build_c",
           "catalog", "generate", "load_generated", "load_python"]
