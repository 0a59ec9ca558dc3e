"""derive: specialised, unrolled Python and C99 Kalman-family filters from SymPy models."""

from importlib.metadata import PackageNotFoundError, version

from . import catalog
from .errors import ModelError
from .model import LinearModel, NonlinearModel

try:
    __version__ = version("derive")
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.1.0"



def generate(model, filters=None, lang="all", out="generated", **options):
    """Generate filters for a model; see :func:`derive.generate.generate`."""
    from .generate import generate as _generate

    return _generate(model, filters, lang, out, options or None)


def build_c(path_or_paths, **kwargs):
    """Compile generated C with cffi; see :func:`derive.build.build_c`."""
    from .build import build_c as _build_c

    return _build_c(path_or_paths, **kwargs)


__all__ = ["LinearModel", "ModelError", "NonlinearModel", "__version__", "build_c", "catalog",
           "generate"]
