"""Issue 20, hardening round two, for rooms: a checkpoint holds its room, WKT input is bounded, far-from-origin rooms
are refused, and each message names the key the user set.

Every bad input gives a one-line ``ValueError`` (``CheckpointError`` for a checkpoint) naming the value and what is
allowed, before any compute. The crafted checkpoints whose stored scenario is too large, too deep or names a file are
in ``tests/io/test_checkpoint_corpus.py``.
"""

import contextlib
import copy
import json
import os
import signal
import sys
import time
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import open_dict
from safetensors import safe_open
from safetensors.torch import load_file, save_file

import pedrl.embed
from pedrl.cli import CONFIG_DIR
from pedrl.common.checks import shown
from pedrl.configs import embed_geometry
from pedrl.evaluation import load_controller
from pedrl.io import CheckpointError
from pedrl.io.checkpoint import METADATA_KEY
from pedrl.notices import PedrlWarning
from pedrl.scenarios import MAX_VERTICES, MAX_WKT_BYTES, build_scenario, is_wkt_text
from pedrl.train import train

ROOM = "POLYGON ((0 0, 12 0, 12 10, 0 10, 0 0))"
EXITS = [[12, 4, 12, 6]]
CPU = torch.device("cpu")


# ---------------------------------------------------------------------- helpers
_OPENED: list[str] = []
_RECORDING = [False]


def _audit(event, args):
    if _RECORDING[0] and event == "open" and isinstance(args[0], str | bytes | os.PathLike):
        _OPENED.append(os.fsdecode(args[0]))


sys.addaudithook(_audit)  # audit hooks stay for the whole process: it records only inside files_opened()


@contextlib.contextmanager
def files_opened():
    """The paths Python opens inside the block (``open``, ``os.open``: the audit event ``open``)."""
    _OPENED.clear()
    _RECORDING[0] = True
    try:
        yield _OPENED
    finally:
        _RECORDING[0] = False


@contextlib.contextmanager
def deadline(seconds: int):
    """Fail instead of hanging (a FIFO opened for reading waits for a writer)."""

    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def one_line_error(error: BaseException, *fragments: str, longest: int = 400) -> str:
    text = str(error)
    assert "\n" not in text and len(text) <= longest, text[:1000]
    for fragment in fragments:
        assert fragment in text, text
    return text


def custom(geometry, exits=EXITS, **more):
    return build_scenario({"name": "custom", "geometry": str(geometry), "exits": exits, **more})


def compose_custom(wkt: Path, *extra: str):
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = compose(
            config_name="train",
            overrides=[
                "debug=default", "algo=vqql", "algo.num_agents=2", "algo.iterations=1", "algo.trials=2",
                "vq.num_prototypes=8", "env.max_decisions=10", "logger=none", "threads=1", "scenario=custom",
                f"scenario.geometry={wkt}", f"scenario.exits={json.dumps(EXITS).replace(' ', '')}", *extra,
            ],
        )  # fmt: skip
    with open_dict(cfg):
        cfg.progress = False
    return cfg


def restored(path: Path, change) -> Path:
    """A copy of checkpoint ``path`` whose stored config ``change(config)`` edited."""
    with safe_open(str(path), framework="pt") as handle:
        metadata = json.loads(handle.metadata()[METADATA_KEY])
    change(metadata["config"])
    crafted = path.parent / f"crafted_{time.monotonic_ns()}.safetensors"
    save_file(load_file(str(path)), str(crafted), metadata={METADATA_KEY: json.dumps(metadata)})
    return crafted


@pytest.fixture(scope="module")
def custom_run(tmp_path_factory):
    """A seconds-long VQQL run in a custom room read from a WKT file: (checkpoint, config, WKT file)."""
    folder = tmp_path_factory.mktemp("custom_run")
    wkt = folder / "room.wkt"
    wkt.write_text(ROOM)
    cfg = compose_custom(wkt)
    train(cfg, run_dir=folder / "run")
    return folder / "run" / "checkpoints" / "last.safetensors", cfg, wkt


# ---------------------------------------------------------------------- 1. a checkpoint carries its room
def test_a_checkpoint_holds_its_room_and_loading_it_opens_no_other_file(custom_run):
    checkpoint, _, wkt = custom_run
    with safe_open(str(checkpoint), framework="pt") as handle:
        stored = json.loads(handle.metadata()[METADATA_KEY])["config"]["scenario"]
    assert is_wkt_text(stored["geometry"]) and stored["exits"] == EXITS
    with files_opened() as opened:
        policy = load_controller(checkpoint, controller="learned", epsilon=0.0, device=CPU, max_decisions=None)
    assert str(wkt) not in opened and not [path for path in opened if path.endswith(".wkt")]
    assert policy.env_factory.scenario.walkable.equals(custom(wkt).walkable)


def test_resume_compares_the_room_itself_not_the_name_of_its_file(custom_run, tmp_path):
    checkpoint, _, _ = custom_run
    moved = tmp_path / "moved.wkt"  # the room's file moved (same polygon): resume goes on
    moved.write_text(ROOM)
    same = compose_custom(moved, f"resume={checkpoint}")
    assert train(same, run_dir=tmp_path / "same").finished_before  # the same room: the finished run is kept
    moved.write_text("POLYGON ((0 0, 12 0, 12 11, 0 11, 0 0))")  # then edited in place: resume refuses
    with pytest.raises(CheckpointError) as error:
        train(same, run_dir=tmp_path / "edited")
    one_line_error(error.value, "incompatible configuration", "scenario.geometry was", "there and is")


def test_a_checkpoint_naming_its_wkt_file_is_refused_with_how_to_reexport_it(custom_run, tmp_path):
    """Checkpoints written before rooms were stored name the file: refused without opening it, re-exported by
    ``python -m pedrl.embed``, then loaded with the same room."""
    checkpoint, cfg, wkt = custom_run
    old = restored(checkpoint, lambda config: config["scenario"].update(geometry=str(wkt)))
    with files_opened() as opened, pytest.raises(CheckpointError) as error:
        load_controller(old, controller="learned", epsilon=0.0, device=CPU, max_decisions=None)
    one_line_error(error.value, str(old), "names its room's WKT file", "python -m pedrl.embed", longest=600)
    assert str(wkt) not in opened
    resumed = copy.deepcopy(cfg)
    with open_dict(resumed):
        resumed.resume = str(old)
    with pytest.raises(CheckpointError, match="python -m pedrl.embed"):
        train(resumed, run_dir=tmp_path / "resumed")

    pedrl.embed.main([str(old), str(wkt), "--output", str(tmp_path / "embedded.safetensors")])
    policy = load_controller(
        tmp_path / "embedded.safetensors", controller="learned", epsilon=0.0, device=CPU, max_decisions=None
    )
    assert policy.env_factory.scenario.walkable.equals(custom(wkt).walkable)
    with pytest.raises(CheckpointError, match="names no WKT file"):
        embed_geometry(tmp_path / "embedded.safetensors", wkt)


def test_re_exporting_an_old_checkpoint_refuses_a_deep_config_in_one_line_naming_the_checkpoint(custom_run, tmp_path):
    """``python -m pedrl.embed`` bounds the stored config before it walks it (a spawn list nested 600 deep gave a
    RecursionError), and blames the checkpoint it was given, not its ``--output`` path."""
    checkpoint, _, wkt = custom_run
    nested: list = []
    for _ in range(600):
        nested = [nested]

    def deepen(config):
        config["scenario"].update(geometry=str(wkt), spawn=nested)

    old = restored(checkpoint, deepen)
    output = tmp_path / "out.safetensors"
    with pytest.raises(CheckpointError) as error:
        embed_geometry(old, wkt, output=output)
    one_line_error(error.value, str(old), "nested deeper than")
    assert str(output) not in str(error.value) and not output.exists()


# ---------------------------------------------------------------------- 2. WKT input is bounded
@pytest.mark.parametrize(
    ("make", "kind"),
    [
        (lambda folder: os.mkfifo(folder / "room.wkt") or folder / "room.wkt", "a FIFO"),
        (lambda folder: Path("/dev/zero"), "a character device"),
        (lambda folder: folder, "a directory"),
    ],
    ids=["fifo", "dev-zero", "directory"],
)
def test_only_regular_files_are_read(make, kind, tmp_path):
    path = make(tmp_path)
    with deadline(20), pytest.raises(ValueError) as error:
        custom(path)
    one_line_error(error.value, f"scenario.geometry={shown(str(path))}", kind, "not a regular file")


def test_a_wkt_file_over_the_size_limit_is_refused_without_reading_it(tmp_path):
    path = tmp_path / "huge.wkt"
    with open(path, "wb") as handle:
        handle.truncate(MAX_WKT_BYTES + 1)  # sparse: nothing is written, and nothing must be read
    with deadline(20), pytest.raises(ValueError) as error:
        custom(path)
    one_line_error(error.value, "huge.wkt", f"{MAX_WKT_BYTES + 1} bytes", f"at most {MAX_WKT_BYTES}")


def test_utf8_with_a_byte_order_mark_is_read(tmp_path):
    path = tmp_path / "bom.wkt"
    path.write_text(ROOM, encoding="utf-8-sig")
    assert path.read_bytes().startswith(b"\xef\xbb\xbf")
    assert custom(path).walkable.equals(build_scenario({"name": "custom", "geometry": ROOM, "exits": EXITS}).walkable)


def test_a_file_that_is_not_utf8_names_the_key_and_the_file(tmp_path):
    path = tmp_path / "latin1.wkt"
    path.write_bytes((ROOM + " -- café").encode("latin-1"))
    with pytest.raises(ValueError) as error:
        custom(path)
    one_line_error(error.value, f"scenario.geometry={shown(str(path))}", "not UTF-8", "0xe9")


def test_z_coordinates_are_dropped_with_a_warning_and_walls_stay_straight(tmp_path):
    path = tmp_path / "z.wkt"
    path.write_text("POLYGON Z ((0 0 0, 12 0 1, 12 10 2, 0 10 3, 0 0 0))")
    with pytest.warns(PedrlWarning, match="Z coordinates are dropped"):
        walls = custom(path).geometry().walls
    flat = tmp_path / "flat.wkt"
    flat.write_text(ROOM)
    assert torch.equal(walls, custom(flat).geometry().walls)


def test_a_polygon_of_a_million_vertices_is_refused_at_once(tmp_path):
    path = tmp_path / "million.wkt"
    path.write_text("POLYGON ((0 0, " + "1 1, " * 10**6 + "0 0))")
    start = time.perf_counter()
    with deadline(60), pytest.raises(ValueError) as error:
        custom(path)
    assert time.perf_counter() - start < 5.0
    one_line_error(error.value, f"scenario.geometry={shown(str(path))}", "1000002 vertices", f"at most {MAX_VERTICES}")


def test_deeply_nested_wkt_gives_one_line(tmp_path):
    path = tmp_path / "deep.wkt"
    path.write_text("GEOMETRYCOLLECTION (" * 600 + ROOM + ")" * 600)
    with pytest.raises(ValueError) as error:
        custom(path)
    one_line_error(error.value, "deep.wkt", "nest 602 deep", "at most 8")


def test_a_long_path_is_not_echoed_in_full():
    path = "/nowhere/" + "a" * 1_000_000
    with pytest.raises(ValueError) as error:
        custom(path)
    one_line_error(error.value, "scenario.geometry='/nowhere/aaa", "characters", "cannot read it")


# ---------------------------------------------------------------------- 3. far from the origin
def test_a_room_far_from_the_origin_is_refused_with_the_float32_reason(tmp_path):
    path = tmp_path / "utm.wkt"
    path.write_text("POLYGON ((500000 5400000, 500010 5400000, 500010 5400010, 500000 5400010, 500000 5400000))")
    with pytest.raises(ValueError) as error:
        custom(path, exits=[[500010, 5400004, 500010, 5400006]])
    one_line_error(
        error.value, f"scenario.geometry={shown(str(path))}", "float32 positions are 0.5 m apart", "at most 10000 m"
    )


# ---------------------------------------------------------------------- 4. messages name the key the user set
@pytest.mark.parametrize(
    ("config", "room", "start"),
    [
        ({"name": "paper_room"}, {"width": 1e30}, "env.width=1e+30 is invalid"),
        ({"name": "paper_room", "width": 1e30}, {"width": 20.0}, "scenario.width=1e+30 is invalid"),
        ({"name": "corner", "leg": 1}, None, "scenario.leg=1 is invalid: must be > scenario.width=2.0"),
        ({"name": "corridor", "length": 1e30, "spawn_length": 1.0}, None, "scenario.length=1e+30 is invalid"),
        ({"name": "bottleneck", "room_length": 0.5}, None, "scenario.room_length=0.5 is invalid"),
        ({"name": "custom", "geometry": ROOM, "exits": "???"}, None, "scenario.exits is missing"),
        ({"name": "custom", "geometry": "???", "exits": EXITS}, None, "scenario.geometry is missing"),
        ({"name": "custom", "geometry": ROOM, "exits": [[5, 5, 6, 5]]}, None, "scenario.exits[0]=[5, 5, 6, 5] is"),
    ],
)
def test_messages_name_the_key_that_was_set(config, room, start):
    with pytest.raises(ValueError) as error:
        build_scenario(config, room=room)
    assert one_line_error(error.value).startswith(start), str(error.value)


@pytest.mark.parametrize("stored", ["paper_room", 7, ["paper_room"]])
def test_a_stored_scenario_that_is_not_a_mapping_is_refused_in_one_line(custom_run, stored):
    """A checkpoint whose stored ``scenario`` is a string (or a number, a list) is refused naming the value, where it
    gave "dictionary update sequence element #0 has length 1; 2 is required"."""
    crafted = restored(custom_run[0], lambda config: config.update(scenario=stored))
    with pytest.raises(ValueError) as error:
        load_controller(crafted, controller="learned", epsilon=0.0, device=CPU, max_decisions=None)
    message = str(error.value)
    assert "\n" not in message and f"scenario={stored!r}" in message and "must be a mapping" in message
