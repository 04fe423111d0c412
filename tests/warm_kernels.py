"""Compile numba's two largest kernels once, in two processes at once, before the test processes start.

`make test` runs one test process per core (pytest-xdist). On a fresh clone numba's cache is empty, and each test
process compiled the fused trial (about 150 s of one core) and the compiled room's step (about 50 s) for itself, the
same work twice. This script runs the smallest training of the tables (the fused trial) and of the network (the
compiled room's step) side by side, each in its own process, so that the test processes load both from numba's
cache. With the cache warm it costs the two debug runs, a few seconds. Without numba it does nothing.

    python -m tests.warm_kernels
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

RUNS = (["debug=default"], ["debug=default", "algo=dqn"])
"""The overrides of the two debug trainings: the tables' (the fused trial) and the network's (the compiled room)."""


def main() -> int:
    from pedrl._numba import numba_available

    if not numba_available():
        return 0
    root = Path(__file__).resolve().parents[1]
    environment = {**os.environ, "OMP_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory(prefix="pedrl-warm-") as folder:
        runs = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "pedrl.train",
                    *overrides,
                    "threads=1",
                    "progress=false",
                    f"hydra.run.dir={folder}/run{i}",
                ],  # fmt: skip
                cwd=root,
                env=environment,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            )  # fmt: skip
            for i, overrides in enumerate(RUNS)
        ]
        errors = [run.communicate()[1] for run in runs]
    for run, err in zip(runs, errors, strict=True):  # the tests will say what is wrong; the warm-up only reports it
        if run.returncode != 0:
            print(f"warm_kernels: {run.args[3:-1]} exited {run.returncode}: {err.strip()[-500:]}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
