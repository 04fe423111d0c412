"""StateEncoder: observations to state ids, as the trainers encoded them, for every kind of quantizer."""

import pytest
import torch

from pedrl.scenarios import paper_room
from pedrl.sim.sensing import distance_indices, feature_indices
from pedrl.vq import ProcessQuantizers, Quantizer, UnionQuantizer
from pedrl.vq.encoder import EncoderSettings, StateEncoder, quantizer_from_state_dict


def room_and_obs(agents=6, replicas=2, seed=0):
    env = paper_room(width=8.0, length=8.0, door_width=2.0).room(
        num_replicas=replicas, num_agents=agents, max_decisions=5
    )
    obs, info = env.reset(seed=seed)
    return env, obs, info


def settings_of(env, **changes):
    values = dict(
        num_neighbours=env.params.num_neighbours,
        num_walls=env.params.num_walls,
        max_distance=env.max_distance,
        max_speed=env.params.max_speed,
    )
    return EncoderSettings(**(values | changes))


def fitted(states, k=8, seed=0):
    return Quantizer.fit(states, k, generator=torch.Generator().manual_seed(seed), max_iterations=5)[0]


def test_encode_is_prepare_then_the_quantizer():
    env, obs, info = room_and_obs()
    settings = settings_of(env, distance_transform="log")
    encoder = StateEncoder(settings)
    flat = obs.reshape(-1, env.num_features)
    prepared = encoder.prepare(flat, info["num_sensed"].reshape(-1), 0, torch.Generator())
    columns = distance_indices(env.params.num_neighbours, env.params.num_walls)
    assert torch.equal(prepared[:, columns], flat[:, columns].log1p())  # log(1 + d) on every distance
    others = torch.ones(env.num_features, dtype=torch.bool)
    others[columns] = False
    assert torch.equal(prepared[:, others], flat[:, others])  # nothing else changes
    encoder.quantizer = fitted(prepared)
    ids = encoder.encode(obs, info, torch.Generator())
    assert torch.equal(ids, encoder.quantizer.encode(prepared))


def test_random_void_filling_is_drawn_once_per_trial_and_only_from_the_generator():
    env, obs, info = room_and_obs(agents=3)  # 2 of 7 neighbour slots sensed: the others are void
    encoder = StateEncoder(settings_of(env, void_features="random"))
    num_sensed = info["num_sensed"].reshape(-1)
    flat = obs.reshape(-1, env.num_features)
    first = encoder.prepare(flat, num_sensed, 0, torch.Generator().manual_seed(1))
    assert not torch.equal(first, flat)  # void slots filled
    later = encoder.prepare(flat, num_sensed, 3, torch.Generator().manual_seed(99))
    assert torch.equal(first, later)  # same trial: same filling, whatever the generator
    again = StateEncoder(encoder.settings).prepare(flat, num_sensed, 0, torch.Generator().manual_seed(1))
    assert torch.equal(first, again)  # a seed gives the same filling
    per_decision = StateEncoder(settings_of(env, void_features="random", void_draws="decision"))
    a = per_decision.prepare(flat, num_sensed, 3, torch.Generator().manual_seed(1))
    b = per_decision.prepare(flat, num_sensed, 3, torch.Generator().manual_seed(2))
    assert not torch.equal(a, b)


def test_rows_mask_encodes_only_the_agents_in_the_room():
    env, obs, info = room_and_obs()
    encoder = StateEncoder(settings_of(env), fitted(obs.reshape(-1, env.num_features)))
    mask = torch.tensor([True, False] * (obs.shape[0] * obs.shape[1] // 2))
    ids = encoder.encode(obs, info, torch.Generator(), rows_mask=mask)
    full = encoder.encode(obs, info, torch.Generator())
    assert torch.equal(ids[mask], full[mask]) and bool((ids[~mask] == 0).all())


@pytest.mark.parametrize("kind", ["plain", "process", "union"])
def test_every_kind_of_quantizer_round_trips_through_its_state_dict(kind):
    env, obs, info = room_and_obs()
    flat = obs.reshape(-1, env.num_features)
    num_sensed = info["num_sensed"].reshape(-1)
    if kind == "plain":
        quantizer = fitted(flat)
    elif kind == "process":
        quantizer = ProcessQuantizers([fitted(flat, seed=0), fitted(flat, seed=1)])
    else:
        n = int(num_sensed[0])
        index = feature_indices(n, env.params.num_neighbours, env.params.num_walls)
        quantizer = UnionQuantizer().unite(n, index, fitted(flat[:, index]))
    encoder = StateEncoder(settings_of(env), quantizer)
    encoder.check()
    copy = StateEncoder.from_state_dict(encoder.settings, encoder.state_dict())
    assert type(copy.quantizer) is type(quantizer)
    assert torch.equal(copy.encode(obs, info, torch.Generator()), encoder.encode(obs, info, torch.Generator()))
    assert copy.num_states == encoder.num_states == quantizer_from_state_dict(encoder.state_dict()).num_prototypes


def test_check_refuses_a_quantizer_of_other_observations():
    env, obs, _ = room_and_obs()
    flat = obs.reshape(-1, env.num_features)
    with pytest.raises(ValueError, match="reads 27 features: the observations have 28"):
        StateEncoder(settings_of(env), fitted(flat[:, :27])).check()
    index = feature_indices(2, env.params.num_neighbours, env.params.num_walls)
    union = UnionQuantizer().unite(3, index, fitted(flat[:, index]))  # part 3 reading part 2's projection
    with pytest.raises(ValueError, match="part 3: reads features"):
        StateEncoder(settings_of(env), union).check()


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"void_features": "noise"}, "void_features='noise' is invalid"),
        ({"distance_transform": "sqrt"}, "distance_transform='sqrt' is invalid"),
        ({"num_neighbours": -1}, "num_neighbours=-1 is invalid: must be an integer >= 0"),  # 0 senses none: an ablation
    ],
)
def test_bad_settings_are_one_line(values, message):
    env, _, _ = room_and_obs()
    with pytest.raises(ValueError, match=message):
        settings_of(env, **values)
    with pytest.raises(ValueError, match="encoder setting 'colour' is unknown"):
        EncoderSettings.from_metadata({**settings_of(env).to_metadata(), "colour": 1})
