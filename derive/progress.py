"""Progress lines for long derivations, so that a large model does not look like a hang.

A line goes to stderr only when stderr is a terminal, or when the environment variable
``DERIVE_PROGRESS`` is ``1`` (``0`` silences it on a terminal too); pipes and logs stay
quiet by default, so ``derive: error: ...`` remains the only line a failure prints.
"""

from __future__ import annotations

import os
import sys

LARGE_MODEL_STATES = 12
"""Models with at least this many states report each filter they derive."""


def enabled() -> bool:
    setting = os.environ.get("DERIVE_PROGRESS", "")
    if setting in ("0", "1"):
        return setting == "1"
    return sys.stderr.isatty()


def report(message: str) -> None:
    """Print ``derive: MESSAGE`` on stderr if progress lines are enabled."""
    if enabled():
        print(f"derive: {message}", file=sys.stderr, flush=True)
