"""What the report's stages share: directories, the run size and the generated filters.

The generation stage fills ``python`` and ``c`` with the generated modules of every
catalog filter it wrote and verified; the experiment sections run those (generated C
unless a section says otherwise), so every figure is drawn from derive's own code.
"""

from __future__ import annotations

from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

from ...errors import ModelError
from ...pipeline import load_generated


@dataclass
class Context:
    """out: the report directory; generated: where the catalog filters are written;
    scratch: a directory for variants (e.g. other prediction horizons); quick: a reduced
    run (fewer steps and seeds) with every figure and table still produced; label: the
    output directory the generated files' regeneration command names, when ``generated``
    is a scratch directory."""

    out: Path
    generated: Path
    scratch: Path
    quick: bool = False
    label: str | None = None    # the output directory the generated files name (None: real)
    python: dict[tuple[str, str], object] = field(default_factory=dict)
    c: dict[tuple[str, str], object] = field(default_factory=dict)
    sources: dict[tuple[str, str], Path] = field(default_factory=dict)
    background: dict[str, object] = field(default_factory=dict)   # name -> Future

    def result_of(self, name: str, compute):
        """The result of background job ``name`` if one was started (and its process did
        not die), else ``compute()`` here."""
        future = self.background.get(name)
        if future is None:
            return compute()
        try:
            return future.result()
        except BrokenProcessPool:
            return compute()

    @property
    def figures(self) -> Path:
        path = self.out / "figures"
        path.mkdir(parents=True, exist_ok=True)
        return path

    def c_filter(self, model: str, name: str):
        """The compiled generated C filter (a derive.build.FilterModule)."""
        try:
            return self.c[(model, name)]
        except KeyError:
            raise ModelError(f"the report needs the generated C of {model}/{name}, which the "
                             "generation stage did not build") from None

    def py_filter(self, model: str, name: str):
        """The imported generated Python module."""
        try:
            return self.python[(model, name)]
        except KeyError:
            raise ModelError(f"the report needs the generated Python of {model}/{name}, "
                             "which the generation stage did not write") from None

    def variant(self, model, name: str, options: dict, tag: str):
        """Generate, compile and return the C of a filter variant (e.g. pred with N = 3)
        in the scratch directory; the catalog's generated directory is not touched."""
        return load_generated(model, name, options, "c", self.scratch / tag,
                              out_label=f"variants/{tag}").c
