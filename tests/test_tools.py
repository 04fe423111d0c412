"""Every ``python -m`` tool checks its arguments at the door: a missing argument, a value of the wrong type or out of
bounds, an output path that cannot be written, ends in one line ``<tool>: error: ...`` and exit code 2 before any
file is read or anything is computed, where argparse printed its usage (seven lines) or the tool a traceback.

``pedrl-eval``, ``pedrl-train``, ``pedrl-validate`` and ``pedrl-export`` are Hydra applications: their catalogues
are in their own test files (:mod:`tests.refusals`)."""

from __future__ import annotations

import pytest

import pedrl.bench.__main__
import pedrl.embed
import pedrl.evaluation.neighbours
import pedrl.evaluation.resolution
import pedrl.sweep
import pedrl.validation.calibrate

RESOLUTION = "python -m pedrl.evaluation.resolution"
NEIGHBOURS = "python -m pedrl.evaluation.neighbours"
CALIBRATE = "python -m pedrl.validation.calibrate"
BENCH = "python -m pedrl.bench"
EMBED = "python -m pedrl.embed"

CASES = [
    ("resolution-no-argument", pedrl.evaluation.resolution.main, RESOLUTION, [], ("required: checkpoints", "--help")),
    ("resolution-agents-1e9", pedrl.evaluation.resolution.main, RESOLUTION, ["C", "--agents", "1e9"],
     ("--agents", "'1e9' is invalid", "integer in [1, 1000]")),
    ("resolution-agents-0", pedrl.evaluation.resolution.main, RESOLUTION, ["C", "--agents=0"],
     ("--agents", "'0' is invalid", "integer in [1, 1000]")),
    ("resolution-seed--1", pedrl.evaluation.resolution.main, RESOLUTION, ["C", "--seed=-1"],
     ("--seed", "'-1' is invalid", "integer in [0, 4294967295]")),
    ("resolution-positions-0", pedrl.evaluation.resolution.main, RESOLUTION, ["C", "--positions=0"],
     ("--positions", "'0' is invalid")),
    ("resolution-speed-2", pedrl.evaluation.resolution.main, RESOLUTION, ["C", "--speed=2"],
     ("--speed", "'2' is invalid", "number in [0, 1]")),
    ("resolution-speed-nan", pedrl.evaluation.resolution.main, RESOLUTION, ["C", "--speed=nan"],
     ("--speed", "'nan' is invalid")),
    ("neighbours-no-argument", pedrl.evaluation.neighbours.main, NEIGHBOURS, [], ("required: checkpoints",)),
    ("neighbours-places-0", pedrl.evaluation.neighbours.main, NEIGHBOURS, ["C", "--places=0"],
     ("--places", "'0' is invalid", "integer in [1, 10000]")),
    ("neighbours-speed-0", pedrl.evaluation.neighbours.main, NEIGHBOURS, ["C", "--speeds", "0.5", "0"],
     ("--speeds", "'0' is invalid", "number in (0, 1]")),
    ("neighbours-speed-1.5", pedrl.evaluation.neighbours.main, NEIGHBOURS, ["C", "--speeds", "1.5"],
     ("--speeds", "'1.5' is invalid")),
    ("neighbours-crowd-size-0", pedrl.evaluation.neighbours.main, NEIGHBOURS, ["C", "--crowd-size=0"],
     ("--crowd-size", "'0' is invalid")),
    ("neighbours-seed--1", pedrl.evaluation.neighbours.main, NEIGHBOURS, ["C", "--seed=-1"], ("--seed", "'-1'")),
    ("neighbours-places-1e9", pedrl.evaluation.neighbours.main, NEIGHBOURS, ["C", "--places=1e9"],
     ("'1e9' is invalid",)),
    ("neighbours-too-large", pedrl.evaluation.neighbours.main, NEIGHBOURS, ["C", "--places=10000", "--crowds=100000"],
     ("too large", "at most 50,000,000 bodies")),
    ("calibrate-experiment", pedrl.validation.calibrate.main, CALIBRATE, ["--experiment", "nope"],
     ("--experiment", "invalid choice: 'nope'", "pedestrian_walk")),
    ("calibrate-seed", pedrl.validation.calibrate.main, CALIBRATE, ["--seed", "-1"], ("--seed", "'-1' is invalid")),
    ("calibrate-gap-0", pedrl.validation.calibrate.main, CALIBRATE, ["--time-gaps", "0.4", "0"],
     ("--time-gaps", "'0' is invalid", "number in (0, 10]")),
    ("calibrate-gap-nan", pedrl.validation.calibrate.main, CALIBRATE, ["--time-gaps", "nan"], ("'nan' is invalid",)),
    ("bench-threads", pedrl.bench.__main__.main, BENCH, ["--threads", "0"], ("--threads", "'0' is invalid")),
    ("bench-trials", pedrl.bench.__main__.main, BENCH, ["--trials", "x"], ("--trials", "'x' is invalid")),
    ("bench-rooms", pedrl.bench.__main__.main, BENCH, ["--rooms", "1,x"], ("--rooms='1,x' is invalid",)),
    ("bench-device", pedrl.bench.__main__.main, BENCH, ["--device", "tpu"], ("--device='tpu' is invalid",)),
    ("bench-output-a-folder", pedrl.bench.__main__.main, BENCH, ["--output", "D"],
     ("--output", "output file", "it is a folder")),
    ("bench-output-below-a-file", pedrl.bench.__main__.main, BENCH, ["--output", "F/bench.json"],
     ("--output", "is a file, not a folder")),
    ("bench-agents", pedrl.bench.__main__.main, BENCH, ["--agents", "1e5"],
     ("--agents='1e5' is invalid", "comma-separated integers")),
    ("bench-write-docs-a-folder", pedrl.bench.__main__.main, BENCH, ["--only", "walk", "--write-docs", "D"],
     ("--write-docs", "output file", "it is a folder")),
    ("sweep-no-argument", pedrl.sweep.main, "pedrl-sweep", [], ("required: sweep_dir",)),
    ("embed-no-argument", pedrl.embed.main, EMBED, [], ("required: checkpoint, wkt",)),
    ("embed-output-a-folder", pedrl.embed.main, EMBED, ["C", "W", "--output", "D"], ("output file", "it is a folder")),
    ("embed-output-below-a-file", pedrl.embed.main, EMBED, ["C", "W", "--output", "F/new.safetensors"],
     ("output file", "is a file, not a folder")),
]  # fmt: skip


@pytest.mark.parametrize(("main", "program", "args", "fragments"), [pytest.param(*c[1:], id=c[0]) for c in CASES])
def test_every_tool_refuses_a_bad_argument_in_one_line_before_any_work(
    main, program, args, fragments, tmp_path, capsys
):
    folder = tmp_path / "a_folder"
    folder.mkdir()
    (tmp_path / "a_file").write_text("keep me")
    places = {"C": str(tmp_path / "absent.safetensors"), "W": str(tmp_path / "absent.wkt"), "D": str(folder)}
    args = [places.get(arg, arg.replace("F/", f"{tmp_path / 'a_file'}/")) for arg in args]
    with pytest.raises(SystemExit) as exit_info:
        main(args)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert exit_info.value.code == 2, err
    assert len(lines) == 1 and lines[0].startswith(f"{program}: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], f"{fragment!r} not in {lines[0]!r}"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["a_file", "a_folder"]  # nothing written
    assert list(folder.iterdir()) == []


def test_the_resolution_tool_checks_the_room_before_the_first_turn(checkpoint, capsys):
    """``--agents 1000`` in a 10 m x 10 m room: refused in one line by the room's density check, before the table's
    header is printed (it ended in a traceback after it)."""
    with pytest.raises(SystemExit) as exit_info:
        pedrl.evaluation.resolution.main([str(checkpoint), "--agents", "2", "1000"])
    captured = capsys.readouterr()
    assert exit_info.value.code == 2 and captured.out == ""
    assert captured.err.splitlines() == [
        f"{RESOLUTION}: error: num_agents=1000 is invalid: 1000 bodies of radius 0.4 m cannot be placed in a"
        " 10.0 m x 10.0 m room (they would cover 594% of the free area; at most 35%)"
    ]


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    from tests.refusals import train_checkpoint

    return train_checkpoint(tmp_path_factory)
