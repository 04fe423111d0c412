"""One run per folder (issue 20): while a process holds a run folder's lock, a second ``pedrl-train`` into it (or a
resume of it) is refused in one line naming that process; a lock whose holder was killed does not block."""

import os
import signal
import subprocess
import sys

import pytest

from pedrl.io.lock import LOCK_NAME, RunFolderInUseError
from pedrl.train import train

HOLDER = """
import sys, time
from pedrl.io.lock import run_folder_lock
with run_folder_lock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(300)
"""


@pytest.fixture
def holder(tmp_path):
    """A second process that holds the lock of ``tmp_path / "run"``; killed with SIGKILL at the end."""
    folder = tmp_path / "run"
    process = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert process.stdout.readline().strip() == "locked", process.stderr.read()
    yield folder, process
    process.kill()
    process.wait(timeout=60)


def test_a_second_train_into_a_locked_folder_is_refused_and_a_killed_holder_does_not_block(holder, train_config):
    folder, process = holder
    cfg = train_config("algo=vqql", "logger=none", "algo.trials=2", "algo.iterations=1")
    with pytest.raises(RunFolderInUseError, match=rf"run folder '.*run' is in use by .*\(pid {process.pid}\)") as info:
        train(cfg, run_dir=folder)
    assert "\n" not in str(info.value)
    assert sorted(p.name for p in folder.iterdir()) == [LOCK_NAME]  # nothing computed or written
    cfg.resume = True  # a resume is refused the same way (its checkpoint is not even needed to tell)
    (folder / "checkpoints").mkdir()
    (folder / "checkpoints" / "last.safetensors").write_bytes(b"")
    with pytest.raises(RunFolderInUseError, match=rf"pid {process.pid}"):
        train(cfg, run_dir=folder)

    process.send_signal(signal.SIGKILL)
    process.wait(timeout=60)
    assert (folder / LOCK_NAME).read_text().strip() == str(process.pid)  # the stale file stays, unlocked
    (folder / "checkpoints" / "last.safetensors").unlink()
    cfg.resume = None
    result = train(cfg, run_dir=folder)
    assert result.checkpoint.is_file()
    assert not (folder / LOCK_NAME).exists()  # a run that ends removes its lock file


def test_pedrl_train_refuses_a_folder_in_use_in_one_line_before_hydra_writes(holder):
    folder, process = holder
    command = [sys.executable, "-m", "pedrl.train", "debug=default", "logger=none", f"hydra.run.dir={folder}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("pedrl-train: error: run folder "), done.stderr
    assert f"(pid {process.pid})" in lines[0] and "one run per folder" in lines[0]
    assert sorted(p.name for p in folder.iterdir()) == [LOCK_NAME]  # no .hydra/, no log: the first run's record
