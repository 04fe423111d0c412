"""``pedrl-export checkpoint=PATH out=PATH``: a training checkpoint's policy as a small file.

The file holds the state encoder (void filling, distance transform, quantizer) and the Q tables, with the training
config that holds the room they were learned in; ``pedrl.load_policy``, ``pedrl-eval policy=`` and the PettingZoo
adapter read it. It is checked on the way out as on the way in: the checkpoint is refused as ``pedrl-eval`` refuses
it, and nothing is written then.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from pedrl.cli import CONFIG_DIR, checked_groups, run_reporting_errors
from pedrl.common.checks import check_device
from pedrl.io.files import check_outputs


def export(cfg: DictConfig) -> Path:
    """Write ``cfg.out`` from ``cfg.checkpoint``; one-line ``ValueError``/``CheckpointError`` for a bad value."""
    from pedrl.policy_files import export_policy

    for key in ("checkpoint", "out"):
        value = cfg.get(key) if not OmegaConf.is_missing(cfg, key) else None
        if value is None:
            raise ValueError(f"{key} is missing: pass {key}=<path of a .safetensors file>")
        if not isinstance(value, str) or not value.endswith(".safetensors"):
            raise ValueError(f"{key}={value!r} is invalid: must be a path ending in .safetensors")
    if Path(cfg.out).resolve() == Path(cfg.checkpoint).resolve():
        raise ValueError(f"out={cfg.out!r} is invalid: it is the checkpoint itself, which would be overwritten")
    check_outputs(files=[cfg.out])  # before the checkpoint is read
    processes = cfg.get("processes")
    return export_policy(cfg.checkpoint, cfg.out, device=check_device(cfg.get("device", "cpu")), processes=processes)


@checked_groups("pedrl-export", CONFIG_DIR, groups=())
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="export")
def main(cfg: DictConfig) -> None:
    """Export a policy; a bad value or file exits with code 2 and one line."""
    path = run_reporting_errors("pedrl-export", lambda: export(cfg))
    print(f"pedrl-export: wrote {path} ({path.stat().st_size / 2**20:.2f} MiB) from {cfg.checkpoint}")


if __name__ == "__main__":
    main()
