"""IT-VQQL's value transfer (the paper's footnote 1): a new iteration's tables start from the old rows at the nearest
old prototypes, process by process."""

import pytest
import torch

from pedrl.algos.base import Phase
from pedrl.algos.registry import build_trainer
from pedrl.vq import ProcessQuantizers, Quantizer


def quantizer(prototypes):
    prototypes = torch.tensor(prototypes, dtype=torch.float32)
    dim = prototypes.shape[1]
    return Quantizer(mean=torch.zeros(dim), std=torch.ones(dim), prototypes=prototypes)


@pytest.mark.parametrize("per_process", [True, False])
def test_new_rows_are_the_old_rows_at_the_nearest_old_prototype(train_config, tmp_path, per_process):
    cfg = train_config("algo=it_vqql", "algo.value_transfer=true", "processes=2", "algo.tables=agent")
    trainer = build_trainer(cfg, tmp_path)
    old_parts = [quantizer([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]), quantizer([[0.0, 10.0], [10.0, 0.0], [0.0, 0.0]])]
    new_parts = [quantizer([[9.0, 1.0], [1.0, 9.0]]), quantizer([[9.0, 1.0], [1.0, 9.0]])]
    old = ProcessQuantizers(old_parts) if per_process else old_parts[0]
    new = ProcessQuantizers(new_parts) if per_process else new_parts[0]
    old_q = torch.arange(2 * 3 * 3 * 81, dtype=torch.float32).reshape(2, 3, 3, 81)  # A_old = 3 tables
    phase = Phase(index=2, num_agents=4, trials=1, gather_trials=1, gather_epsilon=0.07)
    q_values = trainer.initial_q_values(phase, new, (old, old_q), 81)
    assert q_values.shape == (2, 4, 2, 81)
    nearest = {0: [1, 2], 1: [1, 0]} if per_process else {0: [1, 2], 1: [1, 2]}  # old ids of the new prototypes
    for process in range(2):
        for table in range(4):
            for k in range(2):
                expected = old_q[process, table % 3, nearest[process][k]]
                assert torch.equal(q_values[process, table, k], expected)


def test_without_transfer_tables_start_from_zeros(train_config, tmp_path):
    plain = build_trainer(train_config("algo=it_vqql"), tmp_path)
    phase = Phase(index=2, num_agents=2, trials=1, gather_trials=1, gather_epsilon=0.07)
    old = quantizer([[0.0, 0.0]])
    assert not plain.initial_q_values(phase, quantizer([[1.0, 1.0]]), (old, torch.ones(1, 1, 1, 81)), 81).any()


def test_a_run_starts_its_second_iteration_from_the_first_ones_values(train_config, tmp_path):
    trainer = build_trainer(train_config("algo=it_vqql", "algo.value_transfer=true", "algo.iterations=2"), tmp_path)
    starts = []
    initial = trainer.initial_q_values

    def record(phase, quantizer, previous, num_actions):
        starts.append((previous, initial(phase, quantizer, previous, num_actions).clone()))
        return starts[-1][1].clone()

    trainer.initial_q_values = record
    trainer.fit()
    (first_previous, first), (learned, second) = starts
    assert first_previous is None and not first.any()  # iteration 1: nothing to transfer
    assert learned[1].any() and second.any()  # iteration 2 starts from iteration 1's learned values
    assert set(second.unique().tolist()) <= set(learned[1].unique().tolist())


def test_value_transfer_must_be_a_boolean(train_config, tmp_path):
    with pytest.raises(ValueError, match="value_transfer='yes' is invalid"):
        build_trainer(train_config("algo=it_vqql", "algo.value_transfer=yes"), tmp_path)
