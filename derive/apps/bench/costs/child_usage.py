"""Wall and CPU seconds and peak resident memory of one command, measured so that the
bench's own memory does not count.

Linux keeps a process's peak resident memory across ``exec``: a child forked (or
vforked) from the bench, which holds gigabytes of batch arrays by then, starts with the
bench's peak as its own, and ``os.wait4`` reports that. So the command runs under a small
launcher (a fresh Python that imports nothing else): the launcher spawns the command,
waits for it with ``os.wait4`` and writes the command's usage to a file; the command's
peak then starts from the launcher's few megabytes (:attr:`Usage.launcher_bytes` says
how many, measured in the same call). ``ru_maxrss`` of a waited child covers its waited
descendants too (gcc's cc1).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

_LAUNCHER = r"""
import json, os, sys
report, cmd = sys.argv[1], sys.argv[2:]
with open("/proc/self/status") as f:   # this exec's own peak (ru_maxrss has the parent's)
    own_kb = int(next(line.split()[1] for line in f if line.startswith("VmHWM:")))
pid = os.posix_spawnp(cmd[0], cmd, os.environ)
_, status, usage = os.wait4(pid, 0)
with open(report, "w") as f:
    json.dump({"cpu": usage.ru_utime + usage.ru_stime, "peak_kb": usage.ru_maxrss,
               "launcher_kb": own_kb}, f)
sys.exit(os.waitstatus_to_exitcode(status) & 0xFF)
"""


@dataclass(frozen=True)
class Usage:
    """What one command cost and said: wall and CPU (user + system) seconds, peak resident
    bytes (of the command and its waited descendants), the launcher's own peak (the floor
    under that figure), its exit code and output."""

    seconds: float
    cpu_seconds: float
    peak_bytes: float
    launcher_bytes: float
    returncode: int
    stdout: str
    stderr: str


def run_measured(cmd: Sequence[str], timeout: float | None = None,
                 env: Mapping[str, str] | None = None) -> Usage:
    """Run ``cmd`` to its end under the launcher; TimeoutError (the command and the
    launcher killed) after ``timeout`` seconds. The wall seconds include the launcher's
    start (a few tens of milliseconds)."""
    with tempfile.TemporaryDirectory(prefix="derive-usage-") as tmp:
        report = Path(tmp) / "usage.json"
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-S", "-c", _LAUNCHER, str(report),
                                 *cmd], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                stdin=subprocess.DEVNULL, text=True, env=env,
                                start_new_session=True)
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise TimeoutError(f"{cmd[0]} did not finish in {timeout:g} s") from None
        seconds = time.perf_counter() - start
        if not report.exists():
            raise RuntimeError(f"the usage launcher failed: {err.strip()[-300:]}")
        usage = json.loads(report.read_text())
    # ru_maxrss is in kilobytes on Linux
    return Usage(seconds, usage["cpu"], usage["peak_kb"] * 1024.0,
                 usage["launcher_kb"] * 1024.0, proc.returncode, out, err)
