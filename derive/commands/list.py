"""`derive list`: the catalog models with n, m and the filters available."""

NAME = "list"
ORDER = 10
HELP = "list the catalog models with n, m and the filters available"
EXAMPLE = "derive list"


def add_arguments(parser) -> None:
    pass


def _short_source(text: str, width: int = 48) -> str:
    head = text.split(":")[0].strip()
    return head if len(head) <= width else head[: width - 3] + "..."


def run(args) -> int:
    rows = _cached_rows()
    head = ("model", "kind", "n", "m", "filters", "source")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(5)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)) + "  source")
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[5])
    return 0


def _rows() -> list[tuple[str, ...]]:
    """One row per catalog model: loading the models (SymPy) and asking the registry."""
    from .. import catalog
    from ..filters import available

    rows = []
    for name in catalog.names():
        model = catalog.load(name)
        rows.append((name, model.kind, str(model.n), str(model.m),
                     ", ".join(available(model)), _short_source(model.source)))
    return rows


def _cached_rows() -> list[tuple[str, ...]]:
    """The rows, from the user's cache when it holds those of this very derive: the key
    hashes every file of the installed package (the catalog, the filters, the model
    code) with the Python and SymPy versions, so a cache entry cannot outlive what made
    it; an entry is read only from a directory and file of this user's that no one else
    can write (as derive.build's cache), and anything else is computed anew."""
    import hashlib
    import json
    import os
    import stat
    import sys
    import tempfile
    from importlib import metadata
    from pathlib import Path

    package = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256(f"{sys.version}\0{metadata.version('sympy')}\0".encode())
    for path in sorted(package.rglob("*")):
        if path.suffix in (".py", ".toml", ".jinja") and "__pycache__" not in path.parts:
            digest.update(str(path.relative_to(package)).encode() + b"\0" +
                          path.read_bytes() + b"\0")
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):
        base = os.path.join(os.path.expanduser("~"), ".cache")
    folder = Path(base) / "derive"
    entry = folder / f"list-{digest.hexdigest()[:24]}.json"

    def private(path: Path) -> bool:
        info = os.stat(path)
        return info.st_uid == os.getuid() and not info.st_mode & (stat.S_IWGRP | stat.S_IWOTH)

    try:
        if private(folder) and private(entry):
            return [tuple(row) for row in json.loads(entry.read_text(encoding="utf-8"))]
    except (OSError, ValueError, TypeError):
        pass
    rows = _rows()
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
        if private(folder):
            with tempfile.NamedTemporaryFile("w", dir=folder, delete=False,
                                             encoding="utf-8") as handle:
                json.dump(rows, handle)
            os.replace(handle.name, entry)
    except OSError:
        pass            # no cache: the rows as computed
    return rows
