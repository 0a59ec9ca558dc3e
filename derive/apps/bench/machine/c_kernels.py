"""Small C kernels the bench times (operation latencies, scalar throughput), compiled
through cffi once per compiler, source and flags, and loaded from derive's build cache."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

from ....build import cache_dir, cached_extension, compiler_command, load_module_file


def compiled_kernels(label: str, source: str, declarations: str, flags: Sequence[str]):
    """The cffi ``lib`` of C ``source`` whose functions ``declarations`` declares, compiled
    with ``flags``; cached under ``label`` and a hash of the compiler, source and flags."""
    import cffi  # C builds load cffi only when something is compiled

    key = hashlib.sha256("\0".join([compiler_command(), source, *flags]).encode()).hexdigest()[:16]
    name = f"_derive_{label}_{key}"

    def build(work: Path) -> None:
        ffi = cffi.FFI()
        ffi.cdef(declarations)
        ffi.set_source(name, source, libraries=["m"], extra_compile_args=list(flags))
        ffi.compile(tmpdir=str(work), verbose=False)

    path = cached_extension(cache_dir(), f"{label}-{key}", name, build)
    return load_module_file(name, path).lib
