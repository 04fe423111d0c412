"""Seeded-equality fingerprints of short runs of every learner: the sha256 of each checkpoint's tensors and of the
learning curve (its clock column dropped), for comparing a tree before and after a change that must not change a
number (docs/history.md keeps them). ``python tests/fingerprints.py OUT.json``, from the root of the tree under test.
"""

import hashlib
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, ".")
from omegaconf import open_dict  # noqa: E402

from pedrl.io import load_checkpoint, read_csv  # noqa: E402
from pedrl.train import train  # noqa: E402
from tests.conftest import compose_config  # noqa: E402

RUNS = {
    "vqql": ["algo=vqql"],
    "it_vqql": ["algo=it_vqql"],
    "in_vqql": ["algo=in_vqql"],
    "factored": [
        "algo=it_vqql",
        "vq.per_process=false",
        "vq.factors={own:{num_prototypes:8},neighbour:{num_prototypes:8}}",
    ],
    "dqn": ["algo=dqn", "algo.num_agents=4", "env.max_decisions=40", "algo.trials=8", "algo.iterations=2"],
    "dqn_mix": [
        "algo=dqn",
        "algo.num_agents=4",
        "env.max_decisions=40",
        "algo.trials=6",
        "algo.head=branching",
        "algo.replay_balance=room",
        "mix=[{name: corridor, length: 24.0, width: 3.0, agents: 4}]",
    ],
    "ppo": ["algo=ppo", "algo.num_agents=4", "env.max_decisions=40", "algo.trials=4", "algo.hidden=[32,32]"],
    "it_mix": ["algo=it_vqql", "mix=[{name: corridor, length: 24.0, width: 3.0, agents: 4}]"],
}
SKIP = {"decisions_per_s", "wall_time_s", "time_s"}
out = {}
for name, overrides in RUNS.items():
    d = Path(tempfile.mkdtemp())
    cfg = compose_config("train", ["debug=default", "threads=1", "logger=none", "checkpoint_every=3", *overrides])
    with open_dict(cfg):
        cfg.progress = False
    train(cfg, run_dir=d)
    h = {}
    for ck in sorted((d / "checkpoints").glob("*.safetensors")):
        tensors = load_checkpoint(ck).tensors
        digest = hashlib.sha256()
        for key in sorted(tensors):
            t = tensors[key].contiguous()
            digest.update(key.encode())
            digest.update(str(t.dtype).encode())
            digest.update(t.numpy().tobytes())
        h[ck.name] = digest.hexdigest()[:16]
    rows = read_csv(d / "learning_curve.csv")
    rows = [{k: v for k, v in r.items() if k not in SKIP} for r in rows]
    h["learning_curve.csv"] = hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()[:16]
    h["columns"] = sorted(rows[0]) if rows else []
    out[name] = h
    print(name, {k: v for k, v in h.items() if k != "columns"}, flush=True)
Path(sys.argv[1]).write_text(json.dumps(out, indent=1))
