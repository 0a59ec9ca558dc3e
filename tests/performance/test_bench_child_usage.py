"""derive.apps.bench.costs.child_usage: a command's peak memory is its own, not the bench's
(Linux carries a forked child's peak across exec), and a hung command is killed."""

import sys
import time

import numpy as np
import pytest

from derive.apps.bench.costs.child_usage import run_measured

MB = 1e6


def test_peak_is_the_commands_own_not_the_parents():
    held = np.ones(int(400 * MB) // 8)          # the parent's memory, touched
    child_mb = 120
    code = f"import numpy; a = numpy.ones({int(child_mb * MB) // 8}); print(a.size)"
    usage = run_measured([sys.executable, "-c", code])
    assert usage.returncode == 0
    assert int(usage.stdout) == int(child_mb * MB) // 8
    # the child's array plus an interpreter with NumPy, far below the parent's 400 MB
    assert child_mb * MB < usage.peak_bytes < child_mb * MB + 150 * MB
    assert usage.launcher_bytes < 50 * MB
    assert held.sum() == held.size


def test_failure_is_reported_with_its_exit_code_and_output():
    usage = run_measured([sys.executable, "-c", "import sys; print('no'); sys.exit(3)"])
    assert usage.returncode == 3
    assert usage.stdout.strip() == "no"


def test_a_hung_command_is_killed_after_its_timeout():
    start = time.monotonic()
    with pytest.raises(TimeoutError, match="did not finish in 0.5 s"):
        run_measured(["sleep", "30"], timeout=0.5)
    assert time.monotonic() - start < 10
