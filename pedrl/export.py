"""``pedrl-export checkpoint=PATH out=PATH``: a training checkpoint's policy as a small file.

``out=<name>.safetensors``: the policy file of any learner. ``out=<name>.onnx`` (a network of ``algo=dqn`` only):
the network of learning process ``process`` (default 0) as an ONNX model, with its observation and action contract
in ``<name>.onnx.json`` (:mod:`pedrl.onnx_export`), which onnxruntime runs without pedrl.

A safetensors file holds the state encoder (void filling, distance transform, quantizer) and the Q tables (or the
network), with the training config that holds the room they were learned in; ``pedrl.load_policy``, ``pedrl-eval
policy=`` and the PettingZoo adapter read it. It is checked on the way out as on the way in: the checkpoint is refused
as ``pedrl-eval`` refuses it, and nothing is written then.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from pedrl.cli import CONFIG_DIR, checked_groups, run_reporting_errors
from pedrl.common.checks import check_device, check_integer
from pedrl.io.files import check_outputs


def export(cfg: DictConfig) -> Path:
    """Write ``cfg.out`` from ``cfg.checkpoint``; one-line ``ValueError``/``CheckpointError`` for a bad value."""
    from pedrl.policy_files import export_policy

    for key, endings in (("checkpoint", (".safetensors",)), ("out", (".safetensors", ".onnx"))):
        value = cfg.get(key) if not OmegaConf.is_missing(cfg, key) else None
        if value is None:
            raise ValueError(f"{key} is missing: pass {key}=<path of a {' or '.join(endings)} file>")
        if not isinstance(value, str) or not value.endswith(endings):
            raise ValueError(f"{key}={value!r} is invalid: must be a path ending in {' or '.join(endings)}")
    if Path(cfg.out).resolve() == Path(cfg.checkpoint).resolve():
        raise ValueError(f"out={cfg.out!r} is invalid: it is the checkpoint itself, which would be overwritten")
    device = check_device(cfg.get("device", "cpu"))
    if cfg.out.endswith(".onnx"):
        return _export_onnx(cfg, device)
    if cfg.get("process") is not None:
        raise ValueError(f"process={cfg.get('process')!r} is invalid here: it picks the network of out=<name>.onnx")
    check_outputs(files=[cfg.out])  # before the checkpoint is read
    processes = cfg.get("processes")
    return export_policy(cfg.checkpoint, cfg.out, device=device, processes=processes)


def _export_onnx(cfg: DictConfig, device) -> Path:
    """``out=<name>.onnx``: a network's process ``process`` and its contract (:func:`pedrl.onnx_export.export_onnx`)."""
    from pedrl.policy_files import load_policy, room_factory
    from pedrl.rl.neural import NeuralPolicy

    if cfg.get("processes") is not None:
        raise ValueError(f"processes={cfg.get('processes')!r} is invalid with out=<name>.onnx: pass process=<index>")
    process = cfg.get("process")
    process = 0 if process is None else check_integer("process", process, minimum=0)
    try:
        import onnx  # noqa: F401  (torch's exporter needs it)
    except ImportError:
        raise ValueError("out=<name>.onnx needs the onnx package: pip install 'pedrl[onnx]'") from None
    check_outputs(files=[cfg.out, cfg.out + ".json"])
    policy = load_policy(cfg.checkpoint, device="cpu", kind="checkpoint", hint="it is exported already")
    if not isinstance(policy, NeuralPolicy):
        raise ValueError(
            f"out={cfg.out!r} is invalid for {cfg.checkpoint!r}: ONNX export writes a network (algo=dqn); a table's "
            "policy exports to out=<name>.safetensors"
        )
    from pedrl.onnx_export import export_onnx

    del device  # the network is exported from the CPU
    return export_onnx(policy, room_factory(policy)(num_replicas=1, num_agents=1), cfg.out, process=process)


@checked_groups("pedrl-export", CONFIG_DIR, groups=())
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="export")
def main(cfg: DictConfig) -> None:
    """Export a policy; a bad value or file exits with code 2 and one line."""
    path = run_reporting_errors("pedrl-export", lambda: export(cfg))
    for line in written(path, cfg.checkpoint):
        print(line)


def written(path: Path, checkpoint: str) -> list[str]:
    """What ``pedrl-export`` says of the file it wrote: its size and source, and for an ONNX model of a checkpoint of
    several learning processes, whose replicas it agrees with (:func:`pedrl.onnx_export.process_note`)."""
    lines = [f"pedrl-export: wrote {path} ({path.stat().st_size / 2**20:.2f} MiB) from {checkpoint}"]
    if path.suffix == ".onnx":
        from pedrl.onnx_export import process_note

        note = process_note(f"{path}.json")
        if note is not None:
            lines.append(f"pedrl-export: {path.name} holds {note}")
    return lines


if __name__ == "__main__":
    main()
