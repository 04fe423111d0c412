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
