"""Checkpoints: round trip, atomic writes, and clear errors for bad files."""

import json
import os

import pytest
import torch

from pedrl.io import CheckpointError, load_checkpoint, save_checkpoint


def _tensors():
    g = torch.Generator().manual_seed(1)
    return {
        "q_values": torch.randn(2, 3, 5, 81, generator=g),
        "quantizer/prototypes": torch.randn(5, 28, generator=g),
        "rng/trainer": torch.Generator().manual_seed(1).get_state(),
    }


def test_round_trip_is_exact(tmp_path):
    tensors = _tensors()
    meta = {"algo": "vqql", "iteration": 3, "config": {"seed": 7, "env": {"width": 60.0}}}
    path = save_checkpoint(tmp_path / "ck" / "iter_0003.safetensors", tensors=tensors, metadata=meta)
    loaded = load_checkpoint(path)
    assert set(loaded.tensors) == set(tensors)
    for name, tensor in tensors.items():
        assert torch.equal(loaded.tensors[name], tensor)
        assert loaded.tensors[name].dtype == tensor.dtype
    assert loaded.metadata["algo"] == "vqql" and loaded.metadata["iteration"] == 3
    assert loaded.metadata["config"] == meta["config"]
    assert loaded.metadata["format"] == "pedrl-checkpoint"
    assert loaded.tensors_with_prefix("quantizer").keys() == {"prototypes"}
    generator = torch.Generator()
    generator.set_state(loaded.tensors["rng/trainer"])
    assert torch.equal(torch.rand(4, generator=generator), torch.rand(4, generator=torch.Generator().manual_seed(1)))


def test_overwrite_leaves_no_temporary_files(tmp_path):
    path = tmp_path / "last.safetensors"
    for i in range(3):
        save_checkpoint(path, tensors={"x": torch.full((3,), float(i))}, metadata={"iteration": i})
    assert os.listdir(tmp_path) == ["last.safetensors"]
    assert load_checkpoint(path).tensors["x"].tolist() == [2.0, 2.0, 2.0]


def test_truncated_file_gives_one_line_error(tmp_path):
    path = save_checkpoint(tmp_path / "a.safetensors", tensors=_tensors(), metadata={})
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match="corrupt or truncated") as info:
        load_checkpoint(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "content",
    [b"", b"not a checkpoint at all", b"\x80\x04\x95pickle-ish bytes"],
)
def test_foreign_files_are_rejected(tmp_path, content):
    path = tmp_path / "x.safetensors"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match="x.safetensors"):
        load_checkpoint(path)


def test_safetensors_without_pedrl_metadata_is_rejected(tmp_path):
    from safetensors.torch import save_file

    path = tmp_path / "other.safetensors"
    save_file({"w": torch.zeros(2)}, str(path), metadata={"framework": "something"})
    with pytest.raises(CheckpointError, match="not a pedrl checkpoint"):
        load_checkpoint(path)


def test_newer_format_is_rejected(tmp_path):
    from safetensors.torch import save_file

    path = tmp_path / "future.safetensors"
    header = {"format": "pedrl-checkpoint", "format_version": 99}
    save_file({"w": torch.zeros(2)}, str(path), metadata={"pedrl": json.dumps(header)})
    with pytest.raises(CheckpointError, match="format_version=99"):
        load_checkpoint(path)


def test_missing_file(tmp_path):
    with pytest.raises(CheckpointError, match="does not exist"):
        load_checkpoint(tmp_path / "nope.safetensors")


@pytest.mark.parametrize(
    ("make", "kind"),
    [
        (lambda p: os.mkfifo(p), "a FIFO"),
        (lambda p: os.symlink("/dev/zero", p), "a link to a character device"),
        (lambda p: os.symlink(p.parent / "gone", p), "a dangling link"),
    ],
)
def test_what_is_not_a_regular_file_is_named_as_what_it_is(tmp_path, make, kind):
    """A FIFO (which would block the read) or a link to /dev/zero (an endless one) is said to be what it is, not
    "does not exist"; nothing is read from it."""
    path = tmp_path / "policy.safetensors"
    make(path)
    with pytest.raises(CheckpointError, match=f"is {kind}: only regular files are read") as refused:
        load_checkpoint(path)
    assert "does not exist" not in str(refused.value)


def test_a_directory_is_named_as_one(tmp_path):
    with pytest.raises(CheckpointError, match="is a directory"):
        load_checkpoint(tmp_path)


@pytest.mark.parametrize(
    ("header", "message"),
    [
        ([1, 2, 3], "not a pedrl checkpoint"),
        ({"format": "pedrl-checkpoint", "format_version": "1"}, "format_version='1'"),
        ({"format": "pedrl-checkpoint", "format_version": {"x": 1}}, "format_version="),
    ],
)
def test_malformed_metadata_gives_one_line(tmp_path, header, message):
    from safetensors.torch import save_file

    path = tmp_path / "odd.safetensors"
    save_file({"w": torch.zeros(2)}, str(path), metadata={"pedrl": json.dumps(header)})
    with pytest.raises(CheckpointError, match=message) as info:
        load_checkpoint(path)
    assert "\n" not in str(info.value)


def test_checkpoints_get_the_mode_of_any_new_file(tmp_path):
    previous = os.umask(0o022)
    try:
        path = save_checkpoint(tmp_path / "last.safetensors", tensors=_tensors(), metadata={})
        save_checkpoint(path, tensors=_tensors(), metadata={})  # a replaced file too
        (tmp_path / "other.txt").write_text("x")
    finally:
        os.umask(previous)
    assert path.stat().st_mode & 0o777 == 0o644 == (tmp_path / "other.txt").stat().st_mode & 0o777


def test_a_temporary_left_by_a_kill_is_removed_by_the_next_save(tmp_path):
    stale = tmp_path / ".last.safetensors.1a2b3c4d.tmp"
    stale.write_bytes(b"half a checkpoint")
    other = tmp_path / "notes.txt"
    other.write_text("kept")
    save_checkpoint(tmp_path / "last.safetensors", tensors=_tensors(), metadata={})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.safetensors", "notes.txt"]


@pytest.mark.parametrize("error", ["safetensors", "oserror"])
def test_a_full_disk_gives_one_line_naming_the_file_and_keeps_the_previous_one(tmp_path, monkeypatch, error):
    from safetensors import SafetensorError

    import pedrl.io.checkpoint as checkpoint_module

    path = save_checkpoint(tmp_path / "last.safetensors", tensors=_tensors(), metadata={"iteration": 1})
    before = path.read_bytes()

    def full_disk(tensors, filename, metadata=None):
        with open(filename, "wb") as handle:
            handle.write(b"\0" * 10)  # a few bytes made it to disk
        if error == "safetensors":
            raise SafetensorError("Error while serializing: IoError(Os { code: 28, kind: StorageFull })")
        raise OSError(28, "No space left on device", filename)

    monkeypatch.setattr(checkpoint_module, "save_file", full_disk)
    with pytest.raises(CheckpointError) as info:
        save_checkpoint(path, tensors=_tensors(), metadata={"iteration": 2})
    message = str(info.value)
    assert message.startswith(f"cannot write checkpoint {str(path)!r}: ") and "\n" not in message
    assert "28" in message or "No space" in message
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["last.safetensors"]
