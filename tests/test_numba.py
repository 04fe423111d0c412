"""A corrupt numba cache heals itself: the kernels are recompiled into a fresh cache with one warning line, instead
of an ``UnpicklingError`` traceback on every run until the cache is deleted by hand."""

import os
import subprocess
import sys

import pytest

from pedrl._numba import COMPILED, COMPILING, kernel_sources_stamp, numba_available

pytestmark = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")

# Two small kernels (the greedy choice and its row prefetch): about 1 s to compile in a fresh process.
SCRIPT = """
import torch
from pedrl.rl.kernels import greedy_kernel
q_values = torch.tensor([[0.0, 3.0, 1.0], [5.0, 1.0, 2.0]]).view(1, 1, 2, 3)
print(greedy_kernel(q_values, torch.tensor([1, 0, 1]), torch.zeros(3)).tolist())
"""


def run_kernels(cache_dir, prelude: str = "") -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "OMP_NUM_THREADS": "1"}
    script = prelude + SCRIPT
    return subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)


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


def test_an_edited_kernel_module_compiles_every_kernel_again(tmp_path):
    """numba dates a cache by its kernel's own file; a kernel that inlines another module's (the step kernel the
    reward's) kept running the old code after that module was edited. The stamp of every kernel's cache also dates
    every kernel module: a warm cache is silent, and the same cache under another stamp of those modules (an edit,
    simulated) compiles the kernels again."""
    modules = {path.replace(os.sep, "/") for path, _, _ in kernel_sources_stamp()}
    assert {"sim/rewards.py", "sim/step_kernel.py", "rl/kernels.py"} <= modules
    assert "common/checks.py" not in modules  # no kernels there
    assert run_kernels(tmp_path).returncode == 0
    warm = run_kernels(tmp_path)
    assert warm.returncode == 0 and warm.stderr.strip() == "", warm.stderr
    edited = "import pedrl._numba\npedrl._numba.kernel_sources_stamp = lambda: (('sim/rewards.py', 1, 1),)\n"
    again = run_kernels(tmp_path, prelude=edited)
    assert again.returncode == 0 and again.stdout.strip() == "[0, 1, 0]"
    assert again.stderr.startswith(COMPILING.split("{")[0]), again.stderr


# A tiny kernel of its own module (numba caches a function of a file only), compiled in well under a second.
TINY_KERNEL = """
from pedrl._numba import cached_njit


@cached_njit()
def twice(value):
    return 2 * value
"""


def run_tiny_kernel(folder, *, progress_seconds: float | None = None, **env_vars: str) -> subprocess.CompletedProcess:
    (folder / "tiny_kernel.py").write_text(TINY_KERNEL)
    env = {**os.environ, "OMP_NUM_THREADS": "1", **env_vars}
    env["PYTHONPATH"] = os.pathsep.join([str(folder), env.get("PYTHONPATH", "")])
    script = "from tiny_kernel import twice; print(twice(21))"
    if progress_seconds is not None:  # where a compile this long says it is done
        script = f"import pedrl._numba; pedrl._numba.PROGRESS_SECONDS = {progress_seconds}\n{script}"
    return subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)


def test_a_cold_cache_announces_the_compile_in_one_line_and_a_warm_one_is_silent(tmp_path):
    cache = tmp_path / "cache"
    (tmp_path / "code").mkdir()
    cold = run_tiny_kernel(tmp_path / "code", NUMBA_CACHE_DIR=str(cache))
    assert cold.returncode == 0, cold.stderr
    assert cold.stdout.strip() == "42"
    lines = [line for line in cold.stderr.splitlines() if line.strip()]
    assert lines == [COMPILING.format(folder=cache)]
    assert lines[0].startswith("pedrl: compiling the numba kernels (first run")
    assert list(cache.rglob("tiny_kernel.twice-*.nbi")), "the kernel was not cached in NUMBA_CACHE_DIR"

    warm = run_tiny_kernel(tmp_path / "code", NUMBA_CACHE_DIR=str(cache))
    assert warm.returncode == 0 and warm.stdout.strip() == "42"
    assert warm.stderr.strip() == "", warm.stderr  # loaded from the cache: nothing to say


def test_a_first_run_says_as_each_kernel_is_compiled(tmp_path):
    # the compile of every kernel (here one, made to count as long) is a line when it is done: the first run's progress
    (tmp_path / "code").mkdir()
    cold = run_tiny_kernel(tmp_path / "code", progress_seconds=0.0, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    assert cold.returncode == 0, cold.stderr
    lines = [line for line in cold.stderr.splitlines() if line.strip()]
    assert len(lines) == 2, cold.stderr
    assert lines[0] == COMPILING.format(folder=tmp_path / "cache")
    assert lines[1].startswith(COMPILED.format(kernel="tiny_kernel.twice", callees="", seconds=0.0)[:-4])
    assert lines[1].endswith(" s")
    warm = run_tiny_kernel(tmp_path / "code", progress_seconds=0.0, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    assert warm.stderr.strip() == "", warm.stderr  # loaded from the cache: nothing compiled, nothing to say


def test_without_any_writable_cache_folder_the_kernels_compile_with_one_warning(tmp_path):
    # numba's own setting of where it may cache: a locator that never applies outside IPython leaves it none, as a
    # read-only install with a read-only home would (a root user cannot make a folder read-only for itself).
    (tmp_path / "code").mkdir()
    done = run_tiny_kernel(tmp_path / "code", NUMBA_CACHE_LOCATOR_CLASSES="IPythonCacheLocator")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "42"
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("pedrl: warning: numba has no writable folder for its cache (cannot cache function")
    assert "set NUMBA_CACHE_DIR" in lines[0]
