"""A corrupt numba cache heals itself: the kernels are recompiled into a fresh cache with one warning line, instead
of an ``UnpicklingError`` traceback on every run until the cache is deleted by hand."""

import os
import subprocess
import sys

import pytest

from pedrl._numba import numba_available

pytestmark = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")

# Two small kernels (the greedy choice and its row prefetch): about 1 s to compile in a fresh process.
SCRIPT = """
import torch
from pedrl.rl.kernels import greedy_kernel
q_values = torch.tensor([[0.0, 3.0, 1.0], [5.0, 1.0, 2.0]]).view(1, 1, 2, 3)
print(greedy_kernel(q_values, torch.tensor([1, 0, 1]), torch.zeros(3)).tolist())
"""


def run_kernels(cache_dir) -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300)


def test_a_corrupt_kernel_cache_is_rebuilt_with_one_line(tmp_path):
    first = run_kernels(tmp_path)
    assert first.returncode == 0, first.stderr
    assert first.stdout.strip() == "[0, 1, 0]"
    greedy_index = next(tmp_path.rglob("kernels._greedy-*.nbi"))
    prefetch_data = next(tmp_path.rglob("kernels._prefetch-*.nbc"))
    greedy_index.write_bytes(b"\x80garbage")  # an unreadable index
    prefetch_data.write_bytes(prefetch_data.read_bytes()[:100])  # a truncated data file

    healed = run_kernels(tmp_path)
    assert healed.returncode == 0, healed.stderr
    assert healed.stdout.strip() == "[0, 1, 0]"
    notices = [line for line in healed.stderr.splitlines() if line.strip()]
    assert len(notices) == 1, healed.stderr  # one line for the process, however many kernels healed; no traceback
    (notice,) = notices
    assert notice.startswith("pedrl: warning: numba's cache of pedrl.rl.kernels._"), notice
    assert "could not be read" in notice and "recompiled into a fresh cache" in notice

    again = run_kernels(tmp_path)  # the rewritten cache loads: no notice
    assert again.returncode == 0 and again.stdout.strip() == "[0, 1, 0]"
    assert again.stderr.strip() == "", again.stderr
