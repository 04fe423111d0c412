"""``python -m pedrl.bench``: the e2e rows and their fraction of the matmul peak (a smoke run, no timed targets)."""

import json
import shutil
import subprocess
import sys

import pytest

from pedrl.bench import e2e
from pedrl.bench.__main__ import main


def test_peak_fraction_is_the_rate_over_the_search_rate_at_the_peak():
    rows = e2e.with_peak_fraction([{"agent_decisions_per_s": 1000.0, "prototypes": 4096}], peak=2 * 4096 * 28 * 4000.0)
    assert rows[0]["fraction_of_matmul_peak"] == pytest.approx(0.25)


def test_matmul_peak_is_a_positive_rate():
    assert e2e.matmul_peak("cpu", size=64, repeats=1) > 0


def test_quick_e2e_writes_its_rows(tmp_path):
    output = tmp_path / "bench.json"
    main(["--quick", "--only", "e2e", "--rooms", "1", "--output", str(output)])
    report = json.loads(output.read_text())
    (row,) = report["e2e"]
    assert row["rooms_per_process"] == 1
    assert row["agent_decisions_per_s"] > 0
    assert 0 < row["fraction_of_matmul_peak"] < 1
    assert report["matmul_peak_flop_per_s"] > 0


def _has_commit(commit: str) -> bool:
    if shutil.which("git") is None:
        return False
    found = subprocess.run(
        ["git", "-C", str(e2e.REPOSITORY), "rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}"],
        capture_output=True,
        check=False,
    )
    return found.returncode == 0


REFERENCE = "e228a3c"
"""The torch baseline of docs/performance.md: a tree without pedrl.scenarios, from before the numba kernels."""
needs_history = pytest.mark.skipif(not _has_commit(REFERENCE), reason=f"a clone without commit {REFERENCE} (shallow?)")


@needs_history
def test_a_baseline_of_an_old_commit_runs_its_own_tree_alone(tmp_path):
    # the old tree has no pedrl.scenarios and another pedrl.sim.geometry: a driver that imports this tree's modules,
    # or an editable install's, fails there (ImportError) instead of measuring it
    rows = e2e.measure_commit(REFERENCE, rooms=(1,), trials=1, quick=True, device="cpu")
    (row,) = rows
    assert row["rooms_per_process"] == 1
    assert row["prototypes"] == e2e.QUICK_PROTOTYPES
    assert row["agent_decisions_per_s"] > 0


@needs_history
def test_the_extracted_tree_is_the_commits(tmp_path):
    tree = e2e.extract_tree(REFERENCE, tmp_path)
    assert (tree / "pedrl" / "algos" / "vqql.py").is_file()
    assert not (tree / "pedrl" / "scenarios").exists()  # came later: what broke the old driver


def test_the_driver_imports_pedrl_from_its_tree_only(tmp_path):
    # a stand-in tree beside an import finder that maps pedrl by name (as an editable install's does): after the
    # isolation, pedrl comes from the tree and a module the tree lacks is not filled in from elsewhere
    tree, other = tmp_path / "tree", tmp_path / "other"
    (tree / "pedrl").mkdir(parents=True)
    (tree / "pedrl" / "__init__.py").write_text("WHERE = 'tree'\n")
    (other / "pedrl").mkdir(parents=True)
    (other / "pedrl" / "__init__.py").write_text("WHERE = 'other'\n")
    (other / "pedrl" / "extra.py").write_text("WHERE = 'other'\n")
    script = f"""
import importlib.machinery, importlib.util, json, sys
sys.path.insert(0, {str(e2e.Path(e2e.__file__).parent)!r})
import e2e

class ByName:  # what setuptools' editable finder does: pedrl.* mapped to another folder by name
    @classmethod
    def find_spec(cls, fullname, path=None, target=None):
        if fullname == "pedrl" or fullname.startswith("pedrl."):
            where = {str(other)!r} + "/" + fullname.replace(".", "/")
            search = [where.rsplit("/", 1)[0]]
            return importlib.machinery.PathFinder.find_spec(fullname, search)
        return None

sys.meta_path.append(ByName)
sys.path.insert(0, {str(other)!r})
e2e._isolate(e2e.Path({str(tree)!r}))
import pedrl
try:
    import pedrl.extra
    extra = True
except ImportError:
    extra = False
outside = e2e.modules_outside(e2e.loaded_modules(), e2e.Path({str(tree)!r}))
print(json.dumps({{"where": pedrl.WHERE, "extra": extra, "outside": outside}}))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, cwd=tmp_path)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result == {"where": "tree", "extra": False, "outside": []}


def test_modules_outside_the_tree_are_named(tmp_path):
    inside, outside = str(tmp_path / "tree" / "pedrl" / "a.py"), str(tmp_path / "main" / "pedrl" / "b.py")
    modules = {"pedrl.a": [inside], "pedrl.b": [outside]}
    assert e2e.modules_outside(modules, tmp_path / "tree") == ["pedrl.b"]


@pytest.mark.parametrize(
    ("commit", "fragment"),
    [
        ("b052d33", "predates the learning loop the e2e section times"),
        ("no-such-commit", "is not a commit of the git clone"),
        ("-x", "must name a commit of this clone's history"),
    ],
)
def test_a_baseline_that_cannot_be_measured_is_refused_in_one_line(commit, fragment, tmp_path, capsys):
    if commit == "b052d33" and not _has_commit(commit):
        pytest.skip("a clone without the first commit")
    with pytest.raises(SystemExit) as exit_info:
        main(["--only", "e2e", "--quick", f"--baseline={commit}", "--output", str(tmp_path / "bench.json")])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert exit_info.value.code == 2
    assert len(lines) == 1 and fragment in lines[0] and repr(commit) in lines[0]
    assert not (tmp_path / "bench.json").exists()


def test_a_baseline_outside_the_e2e_section_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--only", "sim", "--quick", "--baseline=HEAD", "--output", str(tmp_path / "bench.json")])
    assert "--baseline is invalid with --only='sim'" in capsys.readouterr().err
