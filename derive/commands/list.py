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
    from .. import catalog
    from ..filters import available

    rows = []
    for name in catalog.names():
        model = catalog.load(name)
        rows.append((name, model.kind, str(model.n), str(model.m),
                     ", ".join(available(model)), _short_source(model.source)))
    head = ("model", "kind", "n", "m", "filters", "source")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(5)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths)) + "  source")
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[5])
    return 0
