"""PPO pieces against hand-computed numbers (Eq. 2-4)."""

import math

import pytest
import torch

from workers.mdrl.ppo import (
    PPOConfig,
    entropy_from_log_probs,
    gae,
    masked_log_probs,
    ppo_losses,
)


def test_table_3_2_defaults_and_derived_rollout():
    cfg = PPOConfig()
    assert (cfg.learning_rate, cfg.clip_coef, cfg.ent_coef, cfg.gamma, cfg.gae_lambda,
            cfg.horizon, cfg.update_epochs) == (3e-4, 0.2, 0.01, 0.99, 0.95, 4000, 50)
    small = PPOConfig(horizon=100, num_envs=8)
    assert small.rollout_steps == 13 and small.batch_steps == 104  # ceil(100 / 8) = 13
    assert PPOConfig.from_dict(small.to_dict()) == small
    with pytest.raises(ValueError, match="gamma"):
        PPOConfig(gamma=1.5)
    with pytest.raises(ValueError, match="unknown field"):
        PPOConfig.from_dict({"lr": 1.0})


def test_gae_three_steps_with_done_in_the_middle():
    # gamma 0.9, lambda 0.8; the episode ends with step 1, so step 1 does not bootstrap and
    # step 0's advantage carries step 1's but nothing from step 2.
    rewards = torch.tensor([1.0, 2.0, 3.0])
    values = torch.tensor([0.5, 1.0, 1.5])
    dones = torch.tensor([False, True, False])
    adv, ret = gae(rewards, values, dones, torch.tensor(2.0), gamma=0.9, lam=0.8)
    # t=2: 3 + 0.9*2.0 - 1.5 = 3.3
    # t=1: 2 + 0 - 1.0 = 1.0 (done: no bootstrap, no carry)
    # t=0: delta = 1 + 0.9*1.0 - 0.5 = 1.4; A = 1.4 + 0.9*0.8*1.0 = 2.12
    torch.testing.assert_close(adv, torch.tensor([2.12, 1.0, 3.3]))
    torch.testing.assert_close(ret, torch.tensor([2.62, 2.0, 4.8]))


def test_gae_batched_columns_are_independent():
    rewards = torch.tensor([[1.0, 0.0], [2.0, 1.0], [3.0, -1.0]])
    values = torch.tensor([[0.5, 0.2], [1.0, 0.1], [1.5, 0.3]])
    dones = torch.tensor([[False, False], [True, False], [False, True]])
    last = torch.tensor([2.0, 7.0])
    adv, _ = gae(rewards, values, dones, last, gamma=0.9, lam=0.8)
    for j in range(2):
        col, _ = gae(rewards[:, j], values[:, j], dones[:, j], last[j], gamma=0.9, lam=0.8)
        torch.testing.assert_close(adv[:, j], col)
    with pytest.raises(ValueError, match="last_value"):
        gae(rewards, values, dones, torch.tensor(1.0), gamma=0.9, lam=0.8)


def test_clipped_loss_matches_hand_computation():
    old = torch.log(torch.tensor([0.5, 0.5, 0.5]))
    new = torch.log(torch.tensor([0.7, 0.25, 0.55])).requires_grad_()  # ratios 1.4, 0.5, 1.1
    adv = torch.tensor([1.0, -2.0, 3.0])
    values = torch.tensor([1.0, 2.0])
    returns = torch.tensor([0.0, 4.0])
    entropy = torch.tensor([0.5, 1.0, 1.5])
    out = ppo_losses(new, old, adv, values, returns, entropy,
                     clip_coef=0.2, vf_coef=0.5, ent_coef=0.01)
    # min(r A, clip(r) A): 1.4*1 -> 1.2 (clipped); 0.5*-2=-1 vs 0.8*-2=-1.6 -> -1.6; 1.1*3=3.3
    l_clip = (1.2 - 1.6 + 3.3) / 3
    assert out.pg_loss.item() == pytest.approx(-l_clip)
    assert out.v_loss.item() == pytest.approx((1.0 + 4.0) / 2)
    assert out.entropy.item() == pytest.approx(1.0)
    assert out.loss.item() == pytest.approx(-l_clip + 0.5 * 2.5 - 0.01 * 1.0)
    assert out.clipfrac.item() == pytest.approx(2 / 3)
    r = torch.tensor([1.4, 0.5, 1.1])
    assert out.approx_kl.item() == pytest.approx(((r - 1) - r.log()).mean().item(), rel=1e-5)
    # samples where the clipped term wins (ratio 1.4 with A > 0, ratio 0.5 with A < 0) get no
    # policy gradient; the in-range one gets d(-r A / 3)/d logp = -r A / 3
    out.loss.backward()
    grad = new.grad
    assert grad[0].item() == 0.0
    assert grad[1].item() == 0.0
    assert grad[2].item() == pytest.approx(-(3.0 * 1.1) / 3)


def test_sample_weights_scale_each_surrogate_and_zero_drops_it():
    """weights (expert probation): weight w scales a sample's policy gradient by w and the
    mean still runs over all samples; weight 0 gives that sample no policy gradient."""
    old = torch.log(torch.tensor([0.5, 0.5, 0.5]))
    adv = torch.tensor([1.0, -1.0, 2.0])
    v = torch.zeros(2)
    ent = torch.zeros(3)
    new = torch.log(torch.tensor([0.55, 0.45, 0.5])).requires_grad_()  # ratios in range
    out = ppo_losses(new, old, adv, v, v, ent, clip_coef=0.2, vf_coef=0.5, ent_coef=0.0,
                     weights=torch.tensor([1.0, 0.0, 0.5]))
    r = torch.tensor([1.1, 0.9, 1.0])
    assert out.pg_loss.item() == pytest.approx(-(1.1 * 1.0 + 0.0 + 0.5 * 2.0) / 3)
    out.loss.backward()
    assert new.grad[1].item() == 0.0
    assert new.grad[0].item() == pytest.approx(-(r[0] * 1.0).item() / 3)
    assert new.grad[2].item() == pytest.approx(-(0.5 * r[2] * 2.0).item() / 3)
    with pytest.raises(ValueError, match="weights"):
        ppo_losses(new, old, adv, v, v, ent, clip_coef=0.2, vf_coef=0.5, ent_coef=0.0,
                   weights=torch.ones(2))


def test_value_clipping_uses_the_larger_error():
    z = torch.zeros(1)
    out = ppo_losses(z, z, z, torch.tensor([1.0]), torch.tensor([0.0]), z, clip_coef=0.2,
                     vf_coef=1.0, ent_coef=0.0, old_values=torch.tensor([0.0]), clip_vloss=True)
    assert out.v_loss.item() == pytest.approx(1.0)  # max(1^2, 0.2^2)
    out = ppo_losses(z, z, z, torch.tensor([1.0]), torch.tensor([2.0]), z, clip_coef=0.2,
                     vf_coef=1.0, ent_coef=0.0, old_values=torch.tensor([0.0]), clip_vloss=True)
    assert out.v_loss.item() == pytest.approx(1.8 ** 2)  # clipped value 0.2 is further off


def test_masked_actions_get_zero_probability_and_no_entropy():
    logits = torch.tensor([[5.0, 1.0, 1.0, 0.0]])
    mask = torch.tensor([[False, True, True, False]])
    logp = masked_log_probs(logits, mask)
    probs = logp.exp()
    torch.testing.assert_close(probs, torch.tensor([[0.0, 0.5, 0.5, 0.0]]))
    assert entropy_from_log_probs(logp).item() == pytest.approx(math.log(2))


def test_sampling_respects_masks_follows_probabilities_and_is_seeded():
    from workers.mdrl.rollout import GreedySelector, SampleSelector

    logp = masked_log_probs(torch.tensor([[[0.0, 2.0, 1.0, 5.0]]]).expand(4000, 1, 4),
                            torch.tensor([True, True, True, False]).expand(4000, 1, 4))
    mask = torch.tensor([True, True, True, False]).expand(4000, 1, 4)
    draw = SampleSelector(torch.Generator().manual_seed(1)).select(logp, mask, None)
    again = SampleSelector(torch.Generator().manual_seed(1)).select(logp, mask, None)
    assert torch.equal(draw, again)
    assert not bool((draw == 3).any())  # the masked action is never taken, despite logit 5
    freq = torch.bincount(draw.flatten(), minlength=4).double() / 4000
    p = logp[0, 0].exp().double()
    # 4000 draws: each frequency is within 5 standard errors of its probability
    assert bool(((freq - p).abs() <= 5 * (p * (1 - p) / 4000).sqrt() + 1e-9).all())
    greedy = GreedySelector().select(logp, mask, None)
    assert bool((greedy == 1).all())


def test_joint_actor_head_round_trip():
    import numpy as np

    from workers.mdrl.rollout import PolicyHead

    head = PolicyHead(num_actions=5, agents=2, joint=True)
    assert (head.policy_agents, head.policy_actions) == (1, 25)
    env_mask = np.ones((1, 2, 5), dtype=bool)
    env_mask[0, 1, 4] = False  # agent 1 cannot move right
    jm = head.policy_mask(env_mask)
    assert jm.shape == (1, 1, 25) and jm.sum() == 20
    assert not jm[0, 0, 2 * 5 + 4]  # (agent 0: down, agent 1: right) is invalid
    np.testing.assert_array_equal(head.env_actions(np.array([[2 * 5 + 3]])), [[2, 3]])


def test_invalid_actions_stay_masked_whatever_the_logits() -> None:
    """Finite logits below the old fill (-1e8) made the masked actions the likely ones:
    `drlaas eval` of a model with an actor bias of -1e10 picked invalid moves and crashed."""
    from workers.mdrl.ppo import masked_log_probs
    from workers.mdrl.rollout import GreedySelector, SampleSelector

    mask = torch.tensor([[True, False, True, False], [False, False, False, True]])
    for scale in (1.0, 1e10, -1e10):
        logits = torch.tensor([[0.5, 9.0, -0.5, 3.0], [1.0, 2.0, 3.0, -4.0]]) * scale
        logp = masked_log_probs(logits - (1e10 if scale < 0 else 0.0), mask)
        assert torch.isfinite(logp).all()
        assert torch.allclose(logp.exp().sum(-1), torch.ones(2))
        assert (logp.exp()[~mask] == 0).all()
        greedy = GreedySelector().select(logp, mask, None)
        assert mask.gather(-1, greedy.unsqueeze(-1)).all()
        sampled = SampleSelector(torch.Generator().manual_seed(0)).select(logp, mask, None)
        assert mask.gather(-1, sampled.unsqueeze(-1)).all()
        entropy = -(logp.exp() * logp).sum(-1)
        assert torch.isfinite(entropy).all()
    # an ordinary policy is unchanged: the log-softmax over the valid actions alone
    logits = torch.tensor([[0.5, 9.0, -0.5, 3.0]])
    expect = torch.log_softmax(torch.tensor([0.5, -0.5]), -1)
    assert torch.allclose(masked_log_probs(logits, mask[:1])[0, [0, 2]], expect)
