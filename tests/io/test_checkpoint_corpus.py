"""Crafted checkpoints: none loads, in ``pedrl-eval`` or in a resumed ``pedrl-train``, and no code runs.

Each case starts from a real checkpoint of a seconds-long run and changes one thing: pickle payloads, broken or
huge headers, ``_target_`` metadata (top level and nested: ``builtins.open`` on a canary file, ``os.makedirs``,
``logging.FileHandler``, ``subprocess.run``), wrong shapes and dtypes, NaN tables, a bad generator state, a
negative trial. The canary proves that nothing named in a file was ever called.
"""

import copy
import json
import pickle
import struct
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import open_dict
from safetensors.torch import load_file, save_file

from pedrl.cli import CONFIG_DIR
from pedrl.evaluation import load_controller
from pedrl.io import CheckpointError
from pedrl.io.checkpoint import METADATA_KEY
from pedrl.train import train

CANARY_TEXT = "the canary is alive\n"
BASE = ("algo.iterations=1", "algo.trials=2", "vq.num_prototypes=8", "env.max_decisions=10", "logger=none")
TRAIN_OVERRIDES = {
    "vqql": ("algo=vqql", "algo.num_agents=2", *BASE),
    "in_vqql": (
        "algo=in_vqql",
        "algo.stages=[1,2]",
        "algo.trials=2",
        "vq.num_prototypes=8",
        "env.max_decisions=10",
        "logger=none",
    ),
}


class OpensTheCanary:
    """A pickle payload: unpickling it would empty the canary file."""

    def __init__(self, canary: Path) -> None:
        self.canary = str(canary)

    def __reduce__(self):
        return (open, (self.canary, "w"))


@pytest.fixture(scope="module")
def originals(tmp_path_factory):
    """``last.safetensors`` of a tiny finished run of VQQL and IN-VQQL, and the configs that trained them."""
    made = {}
    for algo, overrides in TRAIN_OVERRIDES.items():
        with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
            cfg = compose(config_name="train", overrides=["debug=default", *overrides, "threads=1"])
        with open_dict(cfg):
            cfg.progress = False
        run_dir = tmp_path_factory.mktemp(f"run_{algo}")
        train(cfg, run_dir=run_dir)
        made[algo] = (run_dir / "checkpoints" / "last.safetensors", cfg)
    return made


@pytest.fixture
def canary(tmp_path):
    path = tmp_path / "canary.txt"
    path.write_text(CANARY_TEXT)
    return path


def _read(path: Path) -> tuple[dict[str, torch.Tensor], dict]:
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as handle:
        metadata = json.loads(handle.metadata()[METADATA_KEY])
    return load_file(str(path)), metadata


def _write(path: Path, tensors: dict[str, torch.Tensor], metadata: dict) -> Path:
    save_file(tensors, str(path), metadata={METADATA_KEY: json.dumps(metadata)})
    return path


# ---------------------------------------------------------------------- the corpus
# Each maker gets (tensors, metadata, canary) and changes them in place, or returns raw bytes for the file.
def _nested(section, key, node):
    def make(tensors, metadata, canary):
        metadata["config"][section][key] = node(canary)

    return make


def _set_meta(key, value):
    def make(tensors, metadata, canary):
        metadata[key] = value

    return make


def _set_tensor(name, value):
    def make(tensors, metadata, canary):
        tensors[name] = value(tensors[name]) if name in tensors else value(None)

    return make


def _drop(prefix):
    def make(tensors, metadata, canary):
        for name in [n for n in tensors if n.startswith(prefix)]:
            del tensors[name]

    return make


def _pickle_file(tensors, metadata, canary):
    return pickle.dumps(OpensTheCanary(canary))


def _torch_save_file(tensors, metadata, canary):
    import io

    buffer = io.BytesIO()
    torch.save({"q_values": tensors["q_values"], "payload": OpensTheCanary(canary)}, buffer)
    return buffer.getvalue()


def _huge_header(tensors, metadata, canary):
    return struct.pack("<Q", 2**62) + b"{" + b" " * 64


def _header_longer_than_file(tensors, metadata, canary):
    return struct.pack("<Q", 50_000_000) + b'{"q_values": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}}'


def _malformed_header(tensors, metadata, canary):
    header = b'{"q_values": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]'
    return struct.pack("<Q", len(header)) + header + b"\0" * 4


def _offsets_past_the_end(tensors, metadata, canary):
    header = b'{"q_values": {"dtype": "F32", "shape": [1000], "data_offsets": [0, 4000]}}'
    return struct.pack("<Q", len(header)) + header + b"\0" * 16


def _deeply_nested_metadata(tensors, metadata, canary):
    deep = "[" * 100_000 + "]" * 100_000
    header = json.dumps(
        {"__metadata__": {METADATA_KEY: deep}, "w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}}
    )
    encoded = header.encode()
    return struct.pack("<Q", len(encoded)) + encoded + b"\0" * 4


def _scenario(**values):
    """Set keys of the stored ``scenario`` (a value that is a function gets the canary's path)."""

    def make(tensors, metadata, canary):
        stored = metadata["config"]["scenario"]
        stored.update({key: value(canary) if callable(value) else value for key, value in values.items()})

    return make


def _nested_list(depth):
    node = [1.0]
    for _ in range(depth):
        node = [node]
    return node


SQUARE = "POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))"
UTM_SQUARE = "POLYGON ((500000 5400000, 500010 5400000, 500010 5400010, 500000 5400010, 500000 5400000))"


def _first_table(tensors, metadata, canary):
    q_values = tensors["q_values"]
    tensors["q_values"] = q_values.clone()
    tensors["q_values"][0, 0, 0, 0] = float("nan")


CORPUS = {
    # files that are not safetensors at all
    "pickle payload": (_pickle_file, "corrupt or truncated"),
    "torch.save payload": (_torch_save_file, "corrupt or truncated"),
    "huge header": (_huge_header, "corrupt or truncated"),
    "header longer than the file": (_header_longer_than_file, "corrupt or truncated"),
    "malformed header": (_malformed_header, "corrupt or truncated"),
    "offsets past the end": (_offsets_past_the_end, "corrupt or truncated"),
    "deeply nested metadata": (_deeply_nested_metadata, "unreadable pedrl metadata"),
    # metadata that names code
    "top-level _target_": (
        lambda t, m, c: m["config"].update({"_target_": "builtins.open", "file": str(c), "mode": "w"}),
        "_target_ is not allowed",
    ),
    "open() nested in env.speed_ratios": (
        _nested("env", "speed_ratios", lambda c: {"_target_": "builtins.open", "file": str(c), "mode": "w"}),
        "env.speed_ratios._target_ is not allowed",
    ),
    "open() in a list": (
        _nested("env", "turn_ratios", lambda c: [0.0, {"_target_": "builtins.open", "file": str(c), "mode": "w"}]),
        "env.turn_ratios\\[1\\]._target_ is not allowed",
    ),
    "os.makedirs as the room": (
        lambda t, m, c: m["config"]["env"].update({"_target_": "os.makedirs", "name": str(c.parent / "made")}),
        "env._target_='os.makedirs' is invalid",
    ),
    "logging.FileHandler nested in vq": (
        _nested("vq", "init", lambda c: {"_target_": "logging.FileHandler", "filename": str(c), "mode": "w"}),
        "vq.init._target_ is not allowed",
    ),
    "subprocess as the trainer": (
        lambda t, m, c: m["config"]["algo"].update({"_target_": "subprocess.run", "args": ["rm", str(c)]}),
        "algo._target_='subprocess.run' is invalid",
    ),
    "_partial_ key": (_nested("env", "_partial_", lambda c: True), "env._partial_ is not allowed"),
    "_args_ key": (_nested("algo", "_args_", lambda c: [str(c)]), "algo._args_ is not allowed"),
    "interpolation": (_nested("env", "width", lambda c: "${oc.env:HOME}"), "holds no interpolation"),
    "unknown room setting": (_nested("env", "file", lambda c: str(c)), "env.file is not a setting"),
    "bad room value": (_nested("env", "width", lambda c: -3.0), "width=-3.0 is invalid"),
    "no config": (lambda t, m, c: m.pop("config"), "holds no training config"),
    # metadata values
    "negative trial": (_set_meta("trial", -7), "trial=-7 is invalid: must be an integer in \\[0, 2\\]"),
    "trial past the phase": (_set_meta("trial", 3), "trial=3 is invalid"),
    "no trial inside a phase": (lambda t, m, c: m.update(trial=0, phase_complete=False), "trial=0 is invalid"),
    "trial as text": (_set_meta("trial", "1"), "trial='1' is invalid"),
    "unknown phase": (_set_meta("iteration", 9), "iteration=9 is invalid"),
    "phase_complete disagrees": (_set_meta("phase_complete", False), "phase_complete=False is invalid"),
    "other algorithm": (_set_meta("algo", "it_vqql"), "it_vqql"),
    "summaries not a list": (_set_meta("summaries", "x"), "summaries are invalid"),
    "negative wall time": (_set_meta("wall_time_s", -1.0), "wall_time_s=-1.0 is invalid"),
    # tensors
    "5 actions": (
        _set_tensor("q_values", lambda q: q[..., :5].contiguous()),
        "q_values is torch.float32 \\(2, 1, 8, 5\\)",
    ),
    "200 actions": (
        _set_tensor("q_values", lambda q: torch.zeros(*q.shape[:3], 200)),
        "must be float32 \\(2, 1, 8, 81\\)",
    ),
    "3 processes": (_set_tensor("q_values", lambda q: torch.zeros(3, *q.shape[1:])), "q_values is torch.float32 \\(3,"),
    "7 tables": (_set_tensor("q_values", lambda q: torch.zeros(q.shape[0], 7, *q.shape[2:])), "\\(2, 7, 8, 81\\)"),
    "wrong K": (_set_tensor("q_values", lambda q: torch.zeros(*q.shape[:2], 9, 81)), "\\(2, 1, 9, 81\\)"),
    "int64 tables": (_set_tensor("q_values", lambda q: q.to(torch.int64)), "q_values is torch.int64"),
    "float64 tables": (_set_tensor("q_values", lambda q: q.double()), "q_values is torch.float64"),
    "NaN table": (_first_table, "q_values holds NaN"),
    "infinite table": (_set_tensor("q_values", lambda q: torch.full_like(q, float("inf"))), "q_values holds NaN"),
    "no tables": (_drop("q_values"), "q_values is missing"),
    "no quantizer": (_drop("quantizer/"), "quantizer tensors"),
    "float64 prototypes": (
        _set_tensor("quantizer/process000/prototypes", lambda p: p.double()),
        "prototypes is torch.float64: must be torch.float32",
    ),
    "NaN prototypes": (
        _set_tensor("quantizer/process001/prototypes", lambda p: torch.full_like(p, float("nan"))),
        "prototypes holds NaN",
    ),
    "wrong feature dimension": (
        _set_tensor("quantizer/process000/prototypes", lambda p: p[:, :5].contiguous()),
        "do not form a quantizer",
    ),
    "one quantizer missing": (_drop("quantizer/process001/"), "holds 1 quantizer"),
    "zero std": (_set_tensor("quantizer/process000/std", lambda s: torch.zeros_like(s)), "do not form a quantizer"),
    "unknown quantizer tensor": (_set_tensor("quantizer/process000/code", lambda s: torch.zeros(3)), "is unknown"),
    "unknown tensor": (_set_tensor("payload", lambda s: torch.zeros(3)), "payload is unknown"),
    "float generator state": (_set_tensor("rng/trainer", lambda s: s.float()), "rng/trainer is torch.float32"),
    "no generator state": (_drop("rng/env"), "rng/env is missing"),
    # the stored scenario (issue 20): the checkpoint holds its room, opens no file it names, and is bounded
    "stored room names a file": (
        _scenario(geometry=str, exits=[[10, 2, 10, 4]]),
        "names its room's WKT file .* re-export it with `python -m pedrl.embed",
    ),
    "stored room names /dev/zero": (_scenario(geometry="/dev/zero", exits=[[10, 2, 10, 4]]), "names its room's WKT"),
    "stored room names a 1 MB path": (
        _scenario(geometry="/tmp/" + "a" * 10**6, exits=[[10, 2, 10, 4]]),
        "1000005 characters\\)\\) instead of holding the room",
    ),
    "100000 stored exits": (
        _scenario(geometry=SQUARE, exits=[[10, 2, 10, 4]] * 10**5),
        "scenario.exits holds 100000 entries: at most 1000",
    ),
    "600-deep stored list": (
        _scenario(geometry=SQUARE, exits=_nested_list(600)),
        "scenario.exits\\[0\\].* is nested deeper than 16 levels",
    ),
    "stored polygon of 100000 vertices": (
        _scenario(geometry="POLYGON ((0 0, " + "1 1, " * 10**5 + "0 0))", exits=[[10, 2, 10, 4]]),
        "100002 vertices, at most 10000",
    ),
    "stored room far from the origin": (
        _scenario(geometry=UTM_SQUARE, exits=[[500010, 5400002, 500010, 5400004]]),
        "float32 positions are 0.5 m apart",
    ),
    "stored scenario name of 10000 characters": (_scenario(name="x" * 10_000), "at most 4096 characters"),
}
UNION_CORPUS = {
    "union part with other features": (
        _set_tensor("quantizer/process000/part1.feature_index", lambda i: i.flip(0).contiguous()),
        "reads features",
    ),
    "union missing a stage": (_drop("quantizer/process000/part1."), "do not form a quantizer"),
    "float num_sensed": (
        _set_tensor("quantizer/process001/num_sensed", lambda n: n.float()),
        "num_sensed is torch.float32",
    ),
}


def _craft(original: Path, folder: Path, make, canary: Path) -> Path:
    tensors, metadata = _read(original)
    tensors, metadata = dict(tensors), copy.deepcopy(metadata)
    raw = make(tensors, metadata, canary)
    path = folder / "crafted.safetensors"
    if isinstance(raw, bytes):
        path.write_bytes(raw)
        return path
    return _write(path, tensors, metadata)


RESUME_ONLY = {
    "negative trial",
    "trial past the phase",
    "no trial inside a phase",
    "unknown phase",
    "phase_complete disagrees",
}
"""Progress that only a resumed run reads, checked against the run's phases by ``pedrl-train resume=``: evaluation
needs no trainer (issue 21), checks only that the trial is an integer >= 0, and acts with the tables it holds."""


def _assert_refused_everywhere(path: Path, cfg, tmp_path: Path, canary: Path, message: str, case: str = "") -> None:
    if case not in RESUME_ONLY:
        with pytest.raises(CheckpointError, match=message) as info:
            load_controller(path, controller="learned", epsilon=0.0, device=torch.device("cpu"), max_decisions=None)
        text = str(info.value)
        assert "\n" not in text and str(path) in text and len(text) < 1000, text[:2000]
        with pytest.raises(CheckpointError) as info:
            load_controller(path, controller="greedy", epsilon=0.0, device=torch.device("cpu"), max_decisions=None)
    run_dir = tmp_path / "resumed"
    with open_dict(cfg):
        cfg.resume = str(path)
    with pytest.raises(CheckpointError) as info:
        train(cfg, run_dir=run_dir)
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    assert not run_dir.exists() or not any(run_dir.iterdir()), "nothing is computed or written"
    assert canary.read_text() == CANARY_TEXT, "no code from the file ran"
    assert not (canary.parent / "made").exists(), "no code from the file ran"


@pytest.mark.parametrize(
    ("algo", "case"), [("vqql", case) for case in CORPUS] + [("in_vqql", case) for case in UNION_CORPUS]
)
def test_crafted_checkpoint_is_refused(algo, case, originals, tmp_path, canary):
    original, cfg = originals[algo]
    make, message = (CORPUS if algo == "vqql" else UNION_CORPUS)[case]
    path = _craft(original, tmp_path, make, canary)
    _assert_refused_everywhere(path, copy.deepcopy(cfg), tmp_path, canary, message, case)


@pytest.mark.parametrize("algo", list(TRAIN_OVERRIDES))
def test_the_untouched_originals_load(algo, originals, tmp_path, canary):
    """The corpus is refused for what was changed, not because every file is refused."""
    original, cfg = originals[algo]
    path = _craft(original, tmp_path, lambda t, m, c: None, canary)
    policy = load_controller(path, controller="learned", epsilon=0.0, device=torch.device("cpu"), max_decisions=None)
    assert policy.processes == 2 and policy.algo == algo
    cfg = copy.deepcopy(cfg)
    with open_dict(cfg):
        cfg.resume = str(path)
    result = train(cfg, run_dir=tmp_path / "resumed")
    assert result.finished_before


def test_pedrl_eval_refuses_a_crafted_checkpoint_in_one_line(originals, tmp_path, canary):
    original, _ = originals["vqql"]
    path = _craft(original, tmp_path, CORPUS["open() nested in env.speed_ratios"][0], canary)
    done = subprocess.run(
        [sys.executable, "-m", "pedrl.evaluate", f"checkpoint={path}", f"hydra.run.dir={tmp_path / 'eval'}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"pedrl-eval: error: checkpoint {str(path)!r}"), done.stderr
    assert "env.speed_ratios._target_ is not allowed" in lines[0]
    assert canary.read_text() == CANARY_TEXT


def test_evaluation_checks_progress_only_as_far_as_acting_needs(originals, tmp_path, canary):
    """A resume refuses the progress cases of RESUME_ONLY against the run's phases; evaluation, which has no
    trainer, still refuses a trial that is not an integer >= 0 and acts with the tables of the others."""
    original, _ = originals["vqql"]
    path = _craft(original, tmp_path, CORPUS["negative trial"][0], canary)
    with pytest.raises(CheckpointError, match="trial=-7 is invalid: must be an integer >= 0"):
        load_controller(path, controller="learned", epsilon=0.0, device=torch.device("cpu"), max_decisions=None)
    for case in sorted(RESUME_ONLY - {"negative trial"}):
        path = _craft(original, tmp_path, CORPUS[case][0], canary)
        loaded = load_controller(
            path, controller="learned", epsilon=0.0, device=torch.device("cpu"), max_decisions=None
        )
        assert loaded.processes == 2, case
