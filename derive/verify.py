"""Verification: generated Python and C against the NumPy reference, on simulated data.

For each filter the generated code is written to a scratch directory, the Python
module imported and the C compiled with the strict flags through cffi, and both
are run over ``steps`` simulated measurements. The error measure is normwise per
step, ``max_k ||gen_k - ref_k||_inf / max(||ref_k||_inf, 1)`` for x(k) and for P(k)
(relative, absolute near zero): a component computed from much larger ones (the
acceleration of the CA model from positions of 1e6 m) is judged at the scale of the
numbers it is computed from. The bar is 1e-12 for linear filters.
"""

from __future__ import annotations

import importlib.util
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import reference, riccati
from .build import build_c
from .emit.write import write_files
from .errors import VerificationError
from .generate import render_filter
from .simulate import simulate_linear

LINEAR_TOLERANCE = 1e-12


@dataclass(frozen=True)
class Verification:
    model: str
    filter: str
    lang: str
    steps: int
    error: float
    tolerance: float

    @property
    def passed(self) -> bool:
        return bool(np.isfinite(self.error) and self.error <= self.tolerance)

    def line(self) -> str:
        mark = "ok  " if self.passed else "FAIL"
        return (f"{mark} {self.model:18s} {self.filter:7s} {self.lang:6s} {self.steps:5d} steps"
                f"  max rel err {self.error:9.2e} <= {self.tolerance:.0e}")


def relative_error(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise VerificationError(f"shape {a.shape} differs from the reference's {b.shape}")
    if a.size == 0:
        return 0.0
    steps = a.shape[0]
    diff = np.abs(a - b).reshape(steps, -1).max(axis=1)
    scale = np.maximum(np.abs(b).reshape(steps, -1).max(axis=1), 1.0)
    return float(np.max(diff / scale))


def import_python(path: Path):
    """Import a generated Python file as a fresh module."""
    spec = importlib.util.spec_from_file_location(f"derive_generated_{path.stem}_{id(path)}",
                                                  path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def reference_run(model, name: str, zs, options: dict):
    """The NumPy reference output for filter ``name``: (xs, Ps or None)."""
    num = model.numeric()
    F, G, H, Q, R, x0, P0 = num.F, num.G, num.H, num.Q, num.R, num.x0, num.P0
    if name in ("kf", "lf", "jklf", "ikf"):
        fn = getattr(reference, name)
        return fn(F, G, H, Q, R, x0, P0, zs)
    if name in ("sskf", "sslf", "jssklf"):
        return getattr(reference, name)(F, G, H, Q, R, x0, zs), None
    if name == "fir":
        return reference.fir(F, G, H, Q, R, zs, N=options["N"]), None
    if name == "pred":
        return reference.pred(F, G, H, Q, R, x0, zs, options.get("N", 1)), None
    raise VerificationError(f"no reference for filter {name!r}")


def _options_for(model, name: str, options: dict) -> dict:
    opts = dict(options)
    if name == "fir" and opts.get("N") is None:
        from .filters.fir import order

        opts["N"] = order(model, opts)
    return opts


def generated_run(module, name: str, zs, model, lang: str):
    """Run a generated filter (Python module or C FilterModule) from the model's x0, P0."""
    num = model.numeric()
    if name in ("kf", "lf", "jklf", "ikf"):
        xs, Ps = module.run(zs, num.x0, num.P0)
        return np.asarray(xs), np.asarray(Ps).reshape(len(zs), model.n, model.n)
    if name == "fir":
        return np.asarray(module.run(zs)), None
    return np.asarray(module.run(zs, num.x0)), None


def verify_filter(model, name: str, steps: int = 1000, seed: int = 7, langs=("python", "c"),
                  options: dict | None = None, workdir: str | Path | None = None
                  ) -> list[Verification]:
    """Generate, build and run filter ``name``; compare with the reference."""
    opts = _options_for(model, name, dict(options or {}))
    num = model.numeric()
    run = simulate_linear(num.F, num.G, num.H, num.Q, num.R, num.x0, steps, seed)
    xs_ref, Ps_ref = reference_run(model, name, run.zs, opts)
    out: list[Verification] = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        files = render_filter(model, name, "all", opts)
        paths = {p.suffix: p for p in write_files(tmp, model.name, files)}
        for lang in langs:
            if lang == "python":
                module = import_python(paths[".py"])
            else:
                module = build_c(paths[".c"])
            xs, Ps = generated_run(module, name, run.zs, model, lang)
            err = relative_error(xs, xs_ref)
            if Ps_ref is not None and Ps is not None:
                err = max(err, relative_error(Ps, Ps_ref))
            out.append(Verification(model.name, name, lang, steps, err, LINEAR_TOLERANCE))
    return out


__all__ = ["Verification", "verify_filter", "relative_error", "riccati"]
