"""derive: specialised, unrolled Python and C99 Kalman-family filters from SymPy models.

The API's names load on first use (PEP 562 ``__getattr__``): ``import derive`` and any
``derive.<submodule>`` import (the command line's, for one) then cost no SymPy or NumPy
import (nor a read of the installed metadata for ``__version__``) until a name that
needs them is read. Type checkers see the imports below.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .errors import ModelError

if TYPE_CHECKING:
    from . import catalog
    from .build import build_c, load_python
    from .fitting import fit
    from .generation import generate
    from .model import LinearModel, NonlinearModel, Sensor
    from .pipeline import load_generated
    from .version import __version__

_LAZY_NAMES = {
    "catalog": "derive.catalog",
    "build_c": "derive.build",
    "fit": "derive.fitting",
    "load_python": "derive.build",
    "generate": "derive.generation",
    "LinearModel": "derive.model",
    "NonlinearModel": "derive.model",
    "Sensor": "derive.model",
    "load_generated": "derive.pipeline",
    "__version__": "derive.version",   # reads the installed metadata: slow
}
"""Each name of the API loaded on first use, and the module that defines it."""

__all__ = ["LinearModel", "ModelError", "NonlinearModel", "Sensor", "__version__", "build_c",
           "catalog", "fit", "generate", "load_generated", "load_python"]


def __getattr__(name: str):
    try:
        module_name = _LAZY_NAMES[name]
    except KeyError:
        raise AttributeError(f"module 'derive' has no attribute {name!r}") from None
    module = importlib.import_module(module_name)
    value = module if module_name == f"derive.{name}" else getattr(module, name)
    globals()[name] = value   # later reads find it without calling here
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
