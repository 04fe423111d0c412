"""TabularPolicy: the agent-to-table rule, acting, and its file (save, load, refusals)."""

import json

import pytest
import torch
from safetensors.torch import load_file, save_file

from pedrl.io import CheckpointError
from pedrl.io.checkpoint import METADATA_KEY
from pedrl.rl import TableLayout, TabularPolicy
from pedrl.scenarios import paper_room
from pedrl.vq import ProcessQuantizers, Quantizer
from pedrl.vq.encoder import EncoderSettings, StateEncoder


class IdInFeatureZero:
    """A hand-made encoder: feature 0 of every observation holds its state id."""

    def encode(self, obs, info, generator, process=None, *, rows_mask=None, process_of_rows=None):
        return obs[..., 0].reshape(-1).long()


def test_agents_use_table_n_mod_a_of_process_i_mod_p():
    processes, tables, states = 2, 3, 4
    q_values = torch.zeros(processes, tables, states, 81)
    for p in range(processes):
        for a in range(tables):
            for s in range(states):
                q_values[p, a, s, 27 * p + 9 * a + s] = 1.0  # each (process, table, state) has its own best action
    policy = TabularPolicy(IdInFeatureZero(), q_values)
    replicas, agents = 4, 7
    state = torch.arange(replicas * agents).remainder(states).view(replicas, agents)
    obs = torch.zeros(replicas, agents, 5)
    obs[..., 0] = state.float()
    actions = policy.act(obs, {})
    replica, agent = torch.arange(replicas)[:, None], torch.arange(agents)[None, :]
    assert torch.equal(actions, 27 * (replica % processes) + 9 * (agent % tables) + state)
    explore = policy.act(obs, {}, epsilon=1.0, generator=torch.Generator().manual_seed(0))
    assert not torch.equal(explore, actions)
    with pytest.raises(ValueError, match="epsilon"):
        policy.controller(epsilon=2.0)


def test_the_training_layout_gives_e_consecutive_rooms_to_each_process():
    layout = TableLayout(processes=3, tables=2, num_states=5, rooms_per_process=2)
    process, rows = layout.of(replicas=6, agents=4, device=torch.device("cpu"))
    assert process.view(6, 4)[:, 0].tolist() == [0, 0, 1, 1, 2, 2]  # rooms p E .. p E + E - 1 learn into p
    table = torch.arange(4).remainder(2)
    assert torch.equal(rows.view(6, 4), ((process.view(6, 4) * 2 + table) * 5))
    assert layout.blocks(6) and not layout.blocks(12)
    evaluation = TableLayout(processes=3, tables=2, num_states=5)
    assert evaluation.of(7, 1, torch.device("cpu"))[0].tolist() == [0, 1, 2, 0, 1, 2, 0]  # replica i: i mod P


def small_policy(per_process=False):
    env = paper_room(width=8.0, length=8.0, door_width=2.0).room(num_replicas=2, num_agents=5, max_decisions=6)
    obs, info = env.reset(seed=3)
    settings = EncoderSettings(
        num_neighbours=env.params.num_neighbours,
        num_walls=env.params.num_walls,
        max_distance=env.max_distance,
        max_speed=env.params.max_speed,
        void_features="random",
    )
    states = torch.randn(200, env.num_features, generator=torch.Generator().manual_seed(0))
    part = Quantizer.fit(states, 6, generator=torch.Generator().manual_seed(0), max_iterations=3)[0]
    quantizer = (
        ProcessQuantizers([part, Quantizer.from_state_dict({k: v.clone() for k, v in part.state_dict().items()})])
        if per_process
        else part
    )
    q_values = torch.randn(2, 5, 6, 81, generator=torch.Generator().manual_seed(1))
    policy = TabularPolicy(StateEncoder(settings, quantizer), q_values, metadata={"algo": "it_vqql"})
    return policy, env, obs, info


@pytest.mark.parametrize("per_process", [False, True])
def test_a_saved_policy_loads_and_acts_the_same(tmp_path, per_process):
    policy, env, obs, info = small_policy(per_process)
    path = policy.save(tmp_path / "policy.safetensors")
    loaded = TabularPolicy.load(path)
    assert loaded.metadata["algo"] == "it_vqql" and loaded.encoder.settings == policy.encoder.settings
    for _ in range(3):
        want = policy.act(obs, info, epsilon=0.2, generator=torch.Generator().manual_seed(5))
        got = loaded.act(obs, info, epsilon=0.2, generator=torch.Generator().manual_seed(5))
        assert torch.equal(want, got)
        obs, _, _, _, info = env.step(want)


def _rewrite(path, change):
    tensors = load_file(str(path))
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as handle:
        metadata = json.loads(handle.metadata()[METADATA_KEY])
    change(tensors, metadata)
    save_file(tensors, str(path), metadata={METADATA_KEY: json.dumps(metadata)})
    return path


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda t, m: m.pop("kind"), "is not an exported policy"),
        (lambda t, m: m.update(policy_version=7), "policy_version=7 is unknown"),
        (lambda t, m: m["encoder"].update(num_walls=3), "reads 28 features: the observations have 30"),
        (lambda t, m: t.update(payload=torch.zeros(2)), "tensor payload is unknown"),
        (lambda t, m: t.pop("q_values"), "q_values is missing"),
        (lambda t, m: t.update(q_values=t["q_values"][..., :9].contiguous()), "q_values is torch.float32"),
        (lambda t, m: t.update(q_values=t["q_values"].double()), "q_values is torch.float64"),
        (lambda t, m: t["q_values"].fill_(float("nan")), "holds NaN"),
        (lambda t, m: t.update({"quantizer/prototypes": t["quantizer/prototypes"].double()}), "must be torch.float32"),
    ],
)
def test_a_crafted_policy_file_is_refused_in_one_line(tmp_path, change, message):
    policy, *_ = small_policy()
    path = _rewrite(policy.save(tmp_path / "policy.safetensors"), change)
    with pytest.raises(CheckpointError, match=message) as error:
        TabularPolicy.load(path)
    assert "\n" not in str(error.value) and str(path) in str(error.value)


@pytest.mark.parametrize(
    ("call", "error", "message"),
    [
        (lambda p, o, i: p.act(o, i, epsilon=float("nan")), ValueError, r"^epsilon=nan is invalid"),
        (lambda p, o, i: p.act(o, i, epsilon=2.0), ValueError, r"^epsilon=2.0 is invalid"),
        (lambda p, o, i: p.act(o[..., :5], i), ValueError, r"^obs is torch.float32 \(2, 5, 5\): must be float"),
        (lambda p, o, i: p.act(o.tolist(), i), TypeError, r"^obs is a list: must be a torch.Tensor"),
        (lambda p, o, i: p.act(o, {}), ValueError, r"^info must be the mapping RoomEnv returns"),
        (lambda p, o, i: p.act(o, i, generator=5), TypeError, r"^generator is a int: must be a torch.Generator"),
    ],
)
def test_bad_arguments_of_act_are_refused_in_one_line(call, error, message):
    """The Python API speaks as the command lines do: a one-line ValueError or TypeError naming the argument, never
    a silent NaN share of random actions or a torch RuntimeError from a wrong width."""
    policy, _, obs, info = small_policy(False)
    with pytest.raises(error, match=message) as caught:
        call(policy, obs, info)
    assert "\n" not in str(caught.value)


def test_every_learner_writes_one_policy_file_and_each_reader_takes_only_its_own(tmp_path):
    """The one writer stores the policy's learner; each class's load reads its own learner's files and refuses
    another's in one line; an unknown learner is refused; a file of tables written before the key reads as tables."""
    from pedrl.rl.network import QNetwork
    from pedrl.rl.neural import NeuralPolicy
    from pedrl.rl.policy import LearnedPolicy, read_policy_file

    tables, *_ = small_policy()
    settings = tables.encoder.settings
    network = QNetwork(1, settings.num_features + settings.num_neighbours, (8,), 81)
    neural = NeuralPolicy(StateEncoder(settings), network, torch.zeros(settings.num_features),
                          torch.ones(settings.num_features))  # fmt: skip
    assert isinstance(tables, LearnedPolicy) and isinstance(neural, LearnedPolicy)
    paths = {policy.learner: policy.save(tmp_path / f"{policy.learner}.safetensors") for policy in (tables, neural)}
    assert isinstance(read_policy_file(paths["table"]), TabularPolicy)
    assert isinstance(read_policy_file(paths["neural"]), NeuralPolicy)
    with pytest.raises(CheckpointError, match="is a policy of learner 'neural', not 'table': load it with") as err:
        TabularPolicy.load(paths["neural"])
    assert "\n" not in str(err.value)
    with pytest.raises(CheckpointError, match="is a policy of learner 'table', not 'neural'"):
        NeuralPolicy.load(paths["table"])
    _rewrite(paths["neural"], lambda t, m: m.update(learner="forest"))
    with pytest.raises(CheckpointError, match="metadata learner='forest' is unknown: allowed: table, neural"):
        read_policy_file(paths["neural"])
    _rewrite(paths["neural"], lambda t, m: m.update(learner=["neural"]))  # crafted: not even a name
    with pytest.raises(CheckpointError, match=r"metadata learner=\['neural'\] is unknown: allowed: table, neural"):
        read_policy_file(paths["neural"])
    _rewrite(paths["table"], lambda t, m: m.pop("learner"))  # as files of tables were written before the key
    torch.testing.assert_close(TabularPolicy.load(paths["table"]).q_values, tables.q_values)


def test_a_policy_hands_itself_to_the_compiled_trial():
    """Tables give the fused trial their arrays, the quantizer packed once however many policies share it, the
    tables a view that sees updates in place; a network gives none (it acts between compiled steps); each names why
    the fused trial cannot run it where it cannot (on another device, tables that do not match the quantizer)."""
    from pedrl.rl.network import QNetwork
    from pedrl.rl.neural import NeuralPolicy

    tables, env, *_ = small_policy()
    arrays = tables.kernel_arrays()
    again = TabularPolicy(tables.encoder, tables.q_values).kernel_arrays()
    assert again.encoder is arrays.encoder and arrays.factored.num_slots == 0
    tables.q_values[1, 2, 3, 4] = 123.0
    assert arrays.table.shape == (2 * 5 * 6, 81) and arrays.table[((1 * 5 + 2) * 6 + 3), 4] == 123.0
    assert tables.kernel_reason(env) is None
    mismatched = TabularPolicy(tables.encoder, torch.zeros(2, 5, 7, 81))
    assert mismatched.kernel_reason(env) == "with tables that do not match the quantizer (processes or prototypes)"
    settings = tables.encoder.settings
    network = QNetwork(1, settings.num_features + settings.num_neighbours, (8,), 81)
    neural = NeuralPolicy(StateEncoder(settings), network, torch.zeros(settings.num_features),
                          torch.ones(settings.num_features))  # fmt: skip
    assert neural.kernel_arrays() is None and neural.kernel_reason(env) is None
