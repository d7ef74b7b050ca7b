"""Table 3.1 networks: Table 3.4 parameter counts, masking, shapes."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from workers.mdrl.networks import ActorCritic, LeNet
from workers.mdrl.observations import ObservationSpec, make_observer

torch.set_num_threads(1)

FOUR_MOVES = 5  # 4 moves + idle (section 3.7)


def ten_by_ten(agents):
    return SimpleNamespace(rows=10, cols=10, agents=agents, walls=(0, 0))


def count(module):
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


@pytest.mark.parametrize(
    "kind,agents,expected",
    [
        ("cmtl", 1, 14837),
        ("cmtl", 2, 15249),
        ("cmtl", 3, 17021),
        ("cmtl", 4, 25593),
        ("cmtl", 5, 68165),
        ("dmtl", 1, 14837),
        ("dmtl", 2, 14909),
        ("odmtl", 1, 4229),
        ("odmtl", 2, 4301),
    ],
)
def test_actor_parameters_match_table_3_4(kind, agents, expected):
    observer = make_observer(ten_by_ten(agents), ObservationSpec(kind, window=3))
    model = ActorCritic.for_observer(observer, FOUR_MOVES)
    assert count(model.actor) == expected


def test_odmtl_critic_is_smaller_than_dmtl_critic():
    odmtl = ActorCritic.for_observer(make_observer(ten_by_ten(3), ObservationSpec("odmtl")), 5)
    dmtl = ActorCritic.for_observer(make_observer(ten_by_ten(3), ObservationSpec("dmtl")), 5)
    assert count(odmtl.critic) < count(dmtl.critic)


def random_obs(observer, b, n, gen):
    actor = torch.rand((b, n) + observer.actor_shape, generator=gen)
    critic = torch.rand((b,) + observer.critic_shape, generator=gen)
    return actor, critic


def test_masked_actions_get_zero_probability():
    gen = torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    observer = make_observer(ten_by_ten(3), ObservationSpec("odmtl"))
    model = ActorCritic.for_observer(observer, 5)
    # scale the head so masked actions would otherwise be likely
    with torch.no_grad():
        model.actor.net[-1].weight.mul_(1000)
    actor_obs, _ = random_obs(observer, 8, 3, gen)
    mask = torch.rand((8, 3, 5), generator=gen) < 0.5
    mask[..., 0] = True  # at least one valid action per agent
    dist = model.dist(actor_obs, mask)
    assert torch.all(dist.probs[~mask] == 0)
    assert torch.allclose(dist.probs.sum(-1), torch.ones(8, 3))
    samples = dist.sample((200,))
    assert torch.all(torch.gather(mask.expand(200, 8, 3, 5), -1, samples[..., None]))


def test_cmtl_joint_mask_masks_joint_logits():
    observer = make_observer(ten_by_ten(2), ObservationSpec("cmtl"))
    model = ActorCritic.for_observer(observer, 5)
    gen = torch.Generator().manual_seed(1)
    actor_obs, critic_obs = random_obs(observer, 4, 1, gen)
    mask = torch.zeros((4, 1, 25), dtype=torch.bool)
    mask[:, :, [3, 7]] = True
    probs = model.dist(actor_obs, mask).probs
    assert probs.shape == (4, 1, 25)
    assert torch.allclose(probs[..., [3, 7]].sum(-1), torch.ones(4, 1))
    assert model.value(critic_obs).shape == (4,)


def test_shapes_follow_leading_dims():
    observer = make_observer(ten_by_ten(3), ObservationSpec("dmtl"))
    model = ActorCritic.for_observer(observer, 9)
    gen = torch.Generator().manual_seed(2)
    actor_obs, critic_obs = random_obs(observer, 6, 3, gen)
    assert model.logits(actor_obs).shape == (6, 3, 9)
    assert model.value(critic_obs).shape == (6,)
    # one env's agents evaluated alone give the same logits as in the batch
    assert torch.allclose(model.logits(actor_obs[2]), model.logits(actor_obs)[2], atol=1e-6)


def test_initial_policy_is_near_uniform():
    torch.manual_seed(0)
    observer = make_observer(ten_by_ten(2), ObservationSpec("odmtl"))
    model = ActorCritic.for_observer(observer, 5)
    actor_obs, _ = random_obs(observer, 16, 2, torch.Generator().manual_seed(3))
    probs = model.dist(actor_obs).probs
    assert torch.allclose(probs, torch.full_like(probs, 0.2), atol=0.02)


def test_networks_read_observer_output():
    rng = np.random.default_rng(0)
    spec = SimpleNamespace(rows=10, cols=10, agents=3, walls=(0, 2))
    b = 4
    env = SimpleNamespace(
        pos=rng.integers(0, 100, (b, 3)),
        readings=rng.random((b, 100)).astype(np.float32),
        visits=np.ones((b, 100), np.float32),
        walls=rng.random((b, 100)) < 0.1,
    )
    env.past_pos = lambda k: env.pos
    for kind in ("cmtl", "dmtl", "odmtl"):
        observer = make_observer(spec, ObservationSpec(kind))
        actor, critic = observer.observe(env)
        model = ActorCritic.for_observer(observer, 5)
        logits = model.logits(torch.from_numpy(actor))
        assert logits.shape == (b, actor.shape[1], observer.num_actor_outputs(5))
        assert model.value(torch.from_numpy(critic)).shape == (b,)


def test_observer_form_of_the_constructor_takes_actor_outputs():
    observer = make_observer(ten_by_ten(2), ObservationSpec("cmtl"))
    model = ActorCritic(observer, 25)
    assert model.actor.outputs == 25 and model.actor.in_shape == observer.actor_shape
    assert model.critic.in_shape == observer.critic_shape
    assert count(model.actor) == count(ActorCritic.for_observer(observer, 5).actor)


def test_bad_inputs_are_rejected():
    net = LeNet((6, 3, 3), 5)
    with pytest.raises(ValueError, match="expects"):
        net(torch.zeros(2, 5, 3, 3))
    model = ActorCritic((6, 3, 3), (3, 3, 3), 5)
    with pytest.raises(ValueError, match="mask"):
        model.logits(torch.zeros(2, 6, 3, 3), torch.ones(2, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match="ActorCritic"):
        ActorCritic((6, 3, 3), (3, 3, 3))
