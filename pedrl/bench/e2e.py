"""End-to-end benchmark: agent-decisions per second of the real VQQL learning loop.

Metrics (wall-clock, best trial of ``trials`` after one warm-up trial, at R = 20 processes, N = 20 agents each,
K = 4096 prototypes; keys of the returned dict):
    - ``e2e``: one row per E (rooms per process) with ``rooms_per_process``, ``agent_decisions_per_s``,
      ``seconds`` (of the best trial) and ``fraction_of_matmul_peak``: the rate as a fraction of the rate that the
      nearest-prototype search alone (``2 K F`` FLOP per decision, F = 28 features) would reach at the float32
      matrix-product peak measured in the same run (``matmul_peak_flop_per_s``).
    - ``e2e_contended`` (``--contention``): the same rows measured while a second torch process multiplies
      matrices on every core (the situation of ``hydra/launcher=parallel`` or of a shared machine).
    - ``e2e_baseline`` (``--baseline COMMIT``): the rows of the same measurement for the code of COMMIT, run from its
      tree alone in a subprocess right before this code's, and ``e2e_speedup`` (this / that, per E).

This file is also the driver that the baseline subprocess runs (``python e2e_driver.py --tree TREE ...``, a copy of
this file outside any tree): the commit's tree is extracted alone with ``git archive`` into a temporary folder, and
the driver imports ``pedrl`` from there and nowhere else (:func:`_isolate` drops the finders and path entries that
would reach another tree, such as an editable install's, and the rows come back with the file of every ``pedrl``
module it loaded, all checked to lie in the tree). Everything below :func:`measure` uses only the API that the first
commit with a learning loop (6e692c4) already had (``VQQL``, ``gather``, ``fit_quantizer``, ``run_trial``), with the
few later names looked up where they exist: the rooms of ``pedrl.scenarios.paper_room`` (a plain
``functools.partial(RoomEnv)`` before the scenarios came), ``env_for`` (``_env`` before), ``zeros_q_values``
(``torch.zeros`` before), ``RunSpec`` (the trainer's own keywords before).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib.machinery
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import torch

PROCESSES, AGENTS, PROTOTYPES, FEATURES = 20, 20, 4096, 28
ROOMS = (1, 4, 16, 32)
"""E values of the default run (docs/performance.md's table); ``--rooms`` picks others."""
QUICK_ROOMS = (1, 2)
QUICK_PROTOTYPES = 512


def _sync(device: str) -> None:
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()


def matmul_peak(device: str = "cpu", *, size: int | None = None, repeats: int = 5) -> float:
    """Float32 matrix-product rate (FLOP/s): best of ``repeats`` products of two ``(size, size)`` matrices."""
    size = size or (8192 if str(device).startswith("cuda") else 1024)
    generator = torch.Generator(device=device).manual_seed(0)
    left = torch.randn(size, size, device=device, generator=generator)
    right = torch.randn(size, size, device=device, generator=generator)
    left @ right  # warm-up
    _sync(device)
    best = float("inf")
    for _ in range(repeats):
        tic = time.perf_counter()
        left @ right
        _sync(device)
        best = min(best, time.perf_counter() - tic)
    return 2.0 * size**3 / best


def measure(*, rooms: Sequence[int], trials: int, quick: bool, device: str) -> list[dict]:
    """Agent-decisions per second of the VQQL loop (``run_trial``) at R = 20, N = 20, for each E in ``rooms``."""
    import pedrl.algos
    from pedrl.algos import VQQL

    prototypes = QUICK_PROTOTYPES if quick else PROTOTYPES
    rooms_of, zeros = _room_factory(), _zeros_q_values()
    rows = []
    for rooms_per_process in rooms:
        run = dict(
            env=rooms_of,
            vq={"num_prototypes": prototypes, "max_iterations": 3, "max_states": 100_000},
            processes=PROCESSES,
            rooms_per_process=rooms_per_process,
            device=device,
            progress=False,
            tensorboard=False,
        )
        # 2 x 20 agents x 200 decisions gathered: enough states per process for K = 4096
        learning = dict(num_agents=AGENTS, trials=1, gather_trials=2)
        if hasattr(pedrl.algos, "RunSpec"):  # the run's keys in a record (a tree from before: the trainer's keywords)
            trainer = VQQL(pedrl.algos.RunSpec(**run), **learning)
        else:
            trainer = VQQL(**run, **learning)
        env = (trainer.env_for if hasattr(trainer, "env_for") else trainer._env)(AGENTS)  # before env_for: _env
        env.reset(seed=0)
        phase = trainer.phases()[0]
        states, num_sensed = trainer.gather(phase, env, None)[:2]
        quantizer, _ = trainer.fit_quantizer(phase, states, num_sensed, None)
        # the tables as the trainers allocate them (this code: in huge pages on the CPU)
        q_values = zeros(PROCESSES, AGENTS, quantizer.num_prototypes, env.num_actions, device=device)
        trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)  # warm-up
        best_rate, best_seconds = 0.0, 0.0
        for _ in range(trials):
            _sync(device)
            tic = time.perf_counter()
            stats = trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)
            _sync(device)
            seconds = time.perf_counter() - tic
            if stats.agent_decisions / seconds > best_rate:
                best_rate, best_seconds = stats.agent_decisions / seconds, seconds
        rows.append(
            {
                "processes": PROCESSES,
                "rooms_per_process": rooms_per_process,
                "agents": AGENTS,
                "prototypes": quantizer.num_prototypes,
                "seconds": best_seconds,
                "agent_decisions_per_s": best_rate,
            }
        )
        print(f"  e2e R={PROCESSES} E={rooms_per_process}: {best_rate:,.0f} agent-decisions/s", flush=True)
    return rows


def _room_factory() -> Callable[..., Any]:
    """The paper's room as the trainers take it: ``paper_room().room``, or, in a tree from before the scenarios
    (whose ``RoomEnv`` was the paper's room by default), ``functools.partial(RoomEnv)``."""
    import importlib.util

    if importlib.util.find_spec("pedrl.scenarios") is not None:
        from pedrl.scenarios import paper_room

        if hasattr(paper_room(), "room"):
            return paper_room().room
    from pedrl.sim import RoomEnv

    return functools.partial(RoomEnv)


def _zeros_q_values() -> Callable[..., torch.Tensor]:
    """Zeroed Q tables ``(R, A, K, U)`` as the trainers allocate them: ``pedrl.rl.zeros_q_values`` (in huge pages on
    the CPU), or ``torch.zeros`` in a tree from before it."""
    try:
        from pedrl.rl import zeros_q_values
    except ImportError:

        def zeros_q_values(*shape: int, device: str) -> torch.Tensor:
            return torch.zeros(shape, device=device)

    return zeros_q_values


def with_peak_fraction(rows: list[dict], peak: float) -> list[dict]:
    """``rows`` with ``fraction_of_matmul_peak``: the rate over ``peak / (2 K F)`` (the search alone at the peak)."""
    return [
        {**row, "fraction_of_matmul_peak": row["agent_decisions_per_s"] * 2.0 * row["prototypes"] * FEATURES / peak}
        for row in rows
    ]


@contextlib.contextmanager
def busy_process() -> Iterator[None]:
    """A second torch process multiplying matrices with torch's default threads, for the time of the block."""
    script = "import torch\na = torch.randn(1024, 1024)\nwhile True:\n    a @ a\n"
    env = {key: value for key, value in os.environ.items() if key != "OMP_NUM_THREADS"}
    process = subprocess.Popen([sys.executable, "-c", script], env=env)
    try:
        time.sleep(1.0)  # let it start
        yield
    finally:
        process.kill()
        process.wait()


REPOSITORY = Path(__file__).resolve().parents[2]
"""The git clone this code runs from, whose history ``--baseline`` reads."""
LOOP_MARK = "agent_decisions"
"""What a commit's trainer holds once its learning loop runs and counts what the e2e section rates (0c8d869 on)."""
LOOP_FOLDERS = ("pedrl/algos", "pedrl/trial")


def _git(*arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(REPOSITORY), *arguments], capture_output=True, check=False)


def baseline_problem(commit: str) -> str | None:
    """Why ``commit`` cannot be measured as a baseline (not a commit of this clone, or no learning loop yet), in one
    line, or None. Asks git only, before any compute."""
    if not commit or commit.startswith("-"):
        return f"--baseline={commit!r} is invalid: must name a commit of this clone's history (a hash, a tag, HEAD~3)"
    if shutil.which("git") is None:
        return f"--baseline={commit!r} needs git on the PATH to read the commit's tree"
    resolved = _git("rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}")
    if resolved.returncode != 0:
        return f"--baseline={commit!r} is not a commit of the git clone at {REPOSITORY}: must name one of its history"
    full = resolved.stdout.decode().strip()
    if _git("grep", "--quiet", "-e", LOOP_MARK, full, "--", *LOOP_FOLDERS).returncode != 0:
        first = _git("log", "--reverse", "--format=%h", f"-S{LOOP_MARK}", "HEAD", "--", *LOOP_FOLDERS)
        since = f": pick {first.stdout.decode().split()[0]} or a later commit" if first.stdout.strip() else ""
        return (
            f"--baseline={commit!r} predates the learning loop the e2e section times"
            f" (no trainer that counts {LOOP_MARK}){since}"
        )
    return None


def extract_tree(commit: str, folder: Path) -> Path:
    """The tree of ``commit`` alone in ``folder/tree`` (``git archive``: the repository itself is only read)."""
    problem = baseline_problem(commit)
    if problem is not None:
        raise ValueError(problem)
    archive = _git("archive", "--format=tar", commit)
    if archive.returncode != 0:
        raise RuntimeError(f"git archive {commit} failed: {archive.stderr.decode().strip()}")
    tree = folder / "tree"
    tree.mkdir()
    with tarfile.open(fileobj=io.BytesIO(archive.stdout)) as tar:
        if hasattr(tarfile, "data_filter"):  # Python 3.11.4 on
            tar.extractall(tree, filter="data")
        else:  # pragma: no cover - git's own archive of a commit of this clone
            tar.extractall(tree)
    return tree


def measure_commit(commit: str, *, rooms: Sequence[int], trials: int, quick: bool, device: str) -> list[dict]:
    """:func:`measure` for the code of ``commit``: its tree alone in a temporary folder, this file's copy run there in a
    subprocess that imports ``pedrl`` from that tree only (checked: every loaded ``pedrl`` module's file)."""
    with tempfile.TemporaryDirectory(prefix="pedrl-baseline-") as name:
        folder = Path(name)
        tree = extract_tree(commit, folder)
        output = folder / "rows.json"
        driver = folder / "e2e_driver.py"  # run from outside any pedrl tree: the import is the extracted tree's
        shutil.copyfile(__file__, driver)
        command = [sys.executable, str(driver), "--tree", str(tree), "--rooms", ",".join(map(str, rooms))]
        command += ["--trials", str(trials), "--device", device, "--output", str(output)]
        command += ["--quick"] if quick else []
        # PYTHONPATH kept (it may hold the dependencies); the driver drops its entries that hold another pedrl
        subprocess.run(command, check=True, cwd=folder)
        result = json.loads(output.read_text())
        outside = modules_outside(result["modules"], tree)
        if outside:  # the driver checks this too; a second look where the rows are read
            raise RuntimeError(f"the baseline of {commit} imported pedrl modules from outside its tree: {outside}")
        return result["rows"]


def modules_outside(modules: dict[str, list[str]], tree: Path) -> list[str]:
    """The names among ``modules`` (name: its files, or a package's folders) with a file outside ``tree``."""
    root = Path(tree).resolve()
    return sorted(
        name for name, files in modules.items() if any(not Path(file).resolve().is_relative_to(root) for file in files)
    )


def _isolate(tree: Path) -> None:
    """Make ``import pedrl`` reach ``tree`` and nothing else: the tree first on ``sys.path``, every other path entry
    that holds a ``pedrl`` package dropped, and every import finder but Python's own that claims ``pedrl`` (an
    editable install's, which maps ``pedrl.*`` to its tree by name and would fill in the modules a baseline tree
    lacks) removed."""
    standard = (importlib.machinery.BuiltinImporter, importlib.machinery.FrozenImporter, importlib.machinery.PathFinder)
    for finder in list(sys.meta_path):
        if finder in standard:
            continue
        try:
            claims = finder.find_spec("pedrl", None) is not None
        except Exception:  # a finder that cannot answer is left alone  # noqa: BLE001
            claims = False
        if claims:
            sys.meta_path.remove(finder)
    root = Path(tree).resolve()
    sys.path[:] = [str(root)] + [
        entry for entry in sys.path if entry and not (Path(entry) / "pedrl").exists() and Path(entry) != root
    ]
    sys.path_importer_cache.clear()
    for name in [name for name in sys.modules if name == "pedrl" or name.startswith("pedrl.")]:
        del sys.modules[name]


def loaded_modules() -> dict[str, list[str]]:
    """Every loaded ``pedrl`` module: its file, or a namespace package's folders."""
    modules = {}
    for name, module in list(sys.modules.items()):
        if name == "pedrl" or name.startswith("pedrl."):
            file = getattr(module, "__file__", None)
            modules[name] = [file] if file else [str(path) for path in getattr(module, "__path__", [])]
    return modules


def run(
    *,
    quick: bool = False,
    device: str = "cpu",
    rooms: Sequence[int] | None = None,
    trials: int | None = None,
    contention: bool = False,
    baseline: str | None = None,
) -> dict:
    """The e2e section of ``python -m pedrl.bench`` (see the module docstring for the keys)."""
    rooms = tuple(rooms or (QUICK_ROOMS if quick else ROOMS))
    trials = trials or (1 if quick else 3)
    report: dict = {}
    if baseline is not None:
        print(f"  baseline {baseline}:", flush=True)
        report["e2e_baseline_commit"] = baseline
        baseline_rows = measure_commit(baseline, rooms=rooms, trials=trials, quick=quick, device=device)
        print("  this code:", flush=True)
    rows = measure(rooms=rooms, trials=trials, quick=quick, device=device)
    peak = matmul_peak(device)
    report["matmul_peak_flop_per_s"] = peak
    report["e2e"] = with_peak_fraction(rows, peak)
    report["e2e_best_agent_decisions_per_s"] = max(row["agent_decisions_per_s"] for row in rows)
    for row in report["e2e"]:
        print(
            f"  e2e E={row['rooms_per_process']}: {row['agent_decisions_per_s']:,.0f} agent-decisions/s ="
            f" {row['fraction_of_matmul_peak']:.1%} of the matmul peak ({peak / 1e9:.0f} GFLOP/s)",
            flush=True,
        )
    if baseline is not None:
        report["e2e_baseline"] = with_peak_fraction(baseline_rows, peak)
        report["e2e_speedup"] = {
            str(new["rooms_per_process"]): new["agent_decisions_per_s"] / old["agent_decisions_per_s"]
            for new, old in zip(rows, baseline_rows, strict=True)
        }
        for key, value in report["e2e_speedup"].items():
            print(f"  e2e E={key}: {value:.2f}x the rate of {baseline}", flush=True)
    if contention:
        print("  with a second busy torch process:", flush=True)
        with busy_process():
            contended = measure(rooms=rooms, trials=trials, quick=quick, device=device)
        report["e2e_contended"] = with_peak_fraction(contended, peak)
    return report


def _driver(argv: list[str] | None = None) -> None:
    """What the baseline subprocess runs: :func:`measure` on the code of ``--tree`` alone, rows and the files of the
    ``pedrl`` modules it loaded written as JSON to ``--output``."""
    parser = argparse.ArgumentParser(description="pedrl e2e driver (run by --baseline)")
    parser.add_argument("--tree", required=True)
    parser.add_argument("--rooms", required=True)
    parser.add_argument("--trials", type=int, required=True)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--output", required=True)
    args = parser.parse_args(argv)
    _isolate(Path(args.tree))
    rooms = [int(value) for value in args.rooms.split(",")]
    rows = measure(rooms=rooms, trials=args.trials, quick=args.quick, device=args.device)
    modules = loaded_modules()
    outside = modules_outside(modules, Path(args.tree))
    if outside:
        raise SystemExit(f"e2e driver: pedrl modules imported from outside {args.tree}: {outside}")
    Path(args.output).write_text(json.dumps({"rows": rows, "modules": modules}))


if __name__ == "__main__":
    _driver()
