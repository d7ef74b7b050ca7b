"""DC / MEDC (Alg. 4.1, 5.1): the selector's rules, the roulette wheel, reproducibility, the
experts (adapters, baselines, faulty ones), learning with an expert, the CLI and the spec."""

import csv
import json

import numpy as np
import pytest
import torch
import typer
from scipy import stats
from typer.testing import CliRunner

from workers.mdrl.baselines import OraclePolicy
from workers.mdrl.checkpoint import load_checkpoint
from workers.mdrl.commands.train import train
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.experts import (
    EnvRows,
    ExpertError,
    action_map,
    load_expert,
    load_experts,
)
from workers.mdrl.medc import DemonstrationConfig, DemonstrationSelector, resume_selector
from workers.mdrl.modelio import load_model
from workers.mdrl.observations import ObservationSpec, make_observer
from workers.mdrl.ppo import PPOConfig, masked_log_probs
from workers.mdrl.rollout import SampleSelector, policy_step
from workers.mdrl.spec import EnvSpec
from workers.mdrl.train import RunConfig, Trainer
from workers.mdrl.trainingspec import SpecError, TrainingSpec, trainingspec_json_schema

TASK = EnvSpec(rows=6, cols=6, agents=3)
TINY_PPO = PPOConfig(horizon=192, num_envs=16, update_epochs=2, num_minibatches=2,
                     learning_rate=1e-3, reward_scale=0.1)  # 12 steps per update


def tiny_run(updates=2, seed=0, **changes):
    return RunConfig(**{**dict(seed=seed, total_steps=updates * TINY_PPO.batch_steps,
                               eval_every=0, eval_episodes=10, checkpoint_every=0,
                               progress=False, tensorboard=False), **changes})


class FixedExpert:
    """Returns given scores (k, N, A) for the rows asked."""

    every_step = False

    def __init__(self, scores, name="fixed"):
        self.s, self.name = np.asarray(scores, dtype=np.float32), name

    def scores(self, env, rows):
        return self.s[rows]


def stepped_env(spec=TASK, envs=16, steps=6, seed=0):
    """An env moved a few random valid steps (agents spread, readings and visits filled)."""
    env = TargetLocalizationEnv(spec, envs, seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        m = env.action_mask()
        r = rng.random(m.shape)
        r[~m] = -1
        env.step(r.argmax(-1))
    return env


def log_probs(p):
    return torch.log(torch.as_tensor(p, dtype=torch.float32).clamp_min(1e-30))


# ---------------------------------------------------------------------------- selector rules


def test_agent_takes_best_ranked_expert_action_above_l_else_its_own_sample():
    # env 0, agent 0: expert ranks 3 > 1 > 2 > 4 > 0 but P(3) = 0.04 <= l -> takes 1
    # env 0, agent 1: best-ranked action 2 is invalid -> next best valid with P > l: 4
    # env 1, agent 0: every ranked action has P <= l (0 is unranked) -> the agent's own sample
    # env 1, agent 1: action 0 is unranked (-inf) despite P = 0.9 -> best ranked with P > l: 3
    p = [[[0.2, 0.3, 0.26, 0.04, 0.2], [0.2, 0.2, 0.2, 0.2, 0.2]],
         [[0.8, 0.05, 0.05, 0.05, 0.05], [0.9, 0.0, 0.0, 0.06, 0.04]]]
    mask = torch.ones(2, 2, 5, dtype=torch.bool)
    mask[0, 1, 2] = False
    ninf = -np.inf
    scores = [[[0, 4, 3, 5, 2], [0, 1, 9, 2, 3]],
              [[ninf, 1, 2, 3, 4], [ninf, 1, 2, 3, 4]]]
    logp = log_probs(p)
    gen = torch.Generator().manual_seed(7)
    sel = DemonstrationSelector([FixedExpert(scores)], rate=1.0, threshold=0.05, generator=gen)
    sel.episode_start(np.arange(2))
    own = SampleSelector(torch.Generator().manual_seed(7)).select(logp, mask, None)
    got = sel.select(logp, mask, None)
    assert got[0, 0] == 1 and got[0, 1] == 4 and got[1, 1] == 3
    assert got[1, 0] == own[1, 0]  # fallback: the very sample plain PPO would have drawn
    assert sel.decisions.tolist() == [4] and sel.followed.tolist() == [3]
    # the expert's own first valid choice only at env 0, agent 1 (3 and 4 fell under l)
    assert sel.agreed.tolist() == [1] and sel.card()["experts"][0]["agreed"] == 1


def test_unguided_episodes_sample_and_the_stored_logp_is_the_learners():
    class Agent:  # a fixed actor: logits per sample
        def logits(self, obs, mask):
            return torch.where(mask, obs.reshape(obs.shape[0], -1), -1e8)

    torch.manual_seed(0)
    obs = torch.randn(3, 2, 5)  # (B, N, 5) used as logits
    mask = torch.ones(3, 2, 5, dtype=torch.bool)
    scores = np.zeros((3, 2, 5), np.float32)
    scores[..., 4] = 1.0  # the expert always prefers action 4
    sel = DemonstrationSelector([FixedExpert(scores)], rate=1.0, threshold=0.0, seed=1)
    sel.episode_start(np.arange(3))
    sel.current[2] = -1  # env 2 follows its own policy
    actions, logp = policy_step(Agent(), obs, mask, sel, None)
    assert (actions[:2] == 4).all()
    learner = masked_log_probs(obs.reshape(6, 5), mask.reshape(6, 5)).reshape(3, 2, 5)
    torch.testing.assert_close(logp, learner.gather(-1, actions.unsqueeze(-1)).squeeze(-1))


def test_joint_cmtl_actor_follows_per_agent_marginals():
    # 2 agents, 3 actions: joint index = 3 * a0 + a1. Joint policy puts 0.5 on (1, 2), 0.5 on
    # (2, 2): marginals a0: [0, .5, .5], a1: [0, 0, 1]. Expert ranks a0: 0 > 2 > 1, a1: 0 > 1 > 2
    p = torch.zeros(1, 1, 9)
    p[0, 0, 3 * 1 + 2] = p[0, 0, 3 * 2 + 2] = 0.5
    scores = np.array([[[3, 1, 2], [3, 2, 1]]], np.float32)

    class Env:
        def action_mask(self):
            return np.ones((1, 2, 3), bool)

    sel = DemonstrationSelector([FixedExpert(scores)], rate=1.0, threshold=0.05)
    sel.episode_start(np.arange(1))
    got = sel.select(log_probs(p), torch.ones(1, 1, 9, dtype=torch.bool), Env())
    assert got.tolist() == [[3 * 2 + 2]]  # a0 = 2 (0 is improbable), a1 = 2 (its only option)


# ---------------------------------------------------------------------------- per episode


def test_roulette_wheel_follows_qos_and_rate():
    qos = (1.0, 2.0, 5.0)
    experts = [FixedExpert(np.zeros((1, 1, 5)), f"e{i}") for i in range(3)]
    sel = DemonstrationSelector(experts, qos=qos, rate=0.3, seed=3)
    n = 40_000
    sel.episode_start(np.arange(n))
    guided = int(sel.episodes.sum())
    assert guided + sel.own_episodes == n
    assert stats.binomtest(guided, n, 0.3).pvalue > 1e-3
    expected = np.array(qos) / sum(qos) * guided
    assert stats.chisquare(sel.episodes, expected).pvalue > 1e-3
    # the test has power: equal weights are rejected outright
    assert stats.chisquare(sel.episodes).pvalue < 1e-12
    assert sel.card()["experts"][2]["selection_probability"] == pytest.approx(5 / 8)


def test_rate_schedule_moves_r_e_linearly_over_the_budget():
    """rate_end: R_E goes from rate to rate_end with the share of the budget done; the guided
    share of episodes follows it, and without rate_end progress changes nothing (Alg. 5.1)."""
    experts = [FixedExpert(np.zeros((1, 1, 5)), f"e{i}") for i in range(2)]
    n = 20_000
    for progress, rate in ((0.0, 0.4), (0.5, 0.2), (0.75, 0.1), (1.0, 0.0), (2.0, 0.0)):
        sel = DemonstrationSelector(experts, rate=0.4, rate_end=0.0, seed=1)
        sel.set_progress(progress)
        assert sel.rate == pytest.approx(rate)
        sel.episode_start(np.arange(n))
        guided = int(sel.episodes.sum())
        if rate == 0.0:
            assert guided == 0
        else:
            assert stats.binomtest(guided, n, rate).pvalue > 1e-3
    fixed = DemonstrationSelector(experts, rate=0.4, seed=1)
    fixed.set_progress(0.9)
    assert fixed.rate == 0.4 and "rate_end" not in fixed.card()
    rising = DemonstrationSelector(experts, rate=0.0, rate_end=0.3, seed=1)
    rising.set_progress(0.5)
    assert rising.rate == pytest.approx(0.15)
    card = rising.card()
    assert (card["rate_start"], card["rate_end"], card["rate"]) == (0.0, 0.3, pytest.approx(0.15))
    restored = DemonstrationSelector(experts, rate=0.0, rate_end=0.3, seed=1)
    restored.load_state_dict(rising.state_dict())  # a resumed run keeps the rate in force
    assert restored.rate == pytest.approx(0.15)


def test_rate_schedule_through_the_trainer_config_and_spec():
    obs = ObservationSpec(kind="odmtl")
    updates = 4
    sel = DemonstrationSelector(load_experts(["oracle"], TASK), rate=0.8, rate_end=0.0, seed=0)
    Trainer(TASK, obs, TINY_PPO, tiny_run(updates=updates), selector=sel).train()
    # the last rollout starts with (updates - 1) of the updates' steps done
    assert sel.rate == pytest.approx(0.8 * (1 - (updates - 1) / updates))
    timed = DemonstrationSelector(load_experts(["oracle"], TASK), rate_end=0.0)
    with pytest.raises(ValueError, match="rate_end"):  # at construction, before any output
        Trainer(TASK, obs, TINY_PPO, tiny_run(total_steps=None, minutes=0.1),
                selector=timed)
    config = DemonstrationConfig.from_dict({"models": ["oracle"], "rate": 0.3, "rate_end": 0.0})
    again = DemonstrationConfig.from_dict(config.to_dict())
    assert (again.rate, again.rate_end) == (0.3, 0.0)
    assert "rate_end" not in DemonstrationConfig(("oracle",)).to_dict()
    with pytest.raises(ValueError, match="rate_end"):
        DemonstrationConfig(("oracle",), rate_end=-0.1)
    doc = {"env": {"rows": 6, "cols": 6, "agents": 3}, "budget": {"steps": 2000},
           "experts": ["a"], "algorithm": {"demonstration": {"rate": 0.2, "rate_end": 0.0}}}
    spec = TrainingSpec.from_dict(doc)
    assert spec.demonstration().rate_end == 0.0 and TrainingSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(SpecError) as info:
        TrainingSpec.from_dict({**doc, "budget": {"minutes": 5}})
    assert info.value.field == "algorithm.demonstration.rate_end"


def test_credit_rule_fades_experts_that_lengthen_episodes():
    """credit=True: an expert whose guided episodes are no shorter than the agents' own loses
    its weight and the guidance share drops with it; one that shortens them by 1/3 keeps all
    of it. Without credit both stay at R_S (the rule is what changes it)."""
    length = {-1: 30, 0: 20, 1: 90}  # episode length by guide: own, good, faulty

    def drive(credit):
        experts = [FixedExpert(np.zeros((1, 1, 5)), n) for n in ("good", "faulty")]
        sel = DemonstrationSelector(experts, rate=0.5, seed=1, credit=credit)
        ids = np.arange(64)
        sel.episode_start(ids)
        for _ in range(100):  # as select() would count: each env runs its guide's length
            sel.steps_in_episode[ids] = [length[int(g)] for g in sel.current[ids]]
            sel.episode_start(ids)
        before = sel.episodes.copy()
        for _ in range(100):
            sel.steps_in_episode[ids] = [length[int(g)] for g in sel.current[ids]]
            sel.episode_start(ids)
        return sel, sel.episodes - before

    sel, late = drive(credit=True)
    f = sel.credit_factors()
    assert f[0] == 1.0 and f[1] == 0.0
    assert sel.mean_length[0] == pytest.approx(20) and sel.mean_length[2] == pytest.approx(30)
    assert late[1] == 0 and late[0] > 0  # the faulty expert guides nothing any more
    card = sel.card()
    assert card["credit"]["rate_in_force"] == pytest.approx(0.5 / 2)
    assert card["experts"][1]["credit"] == 0.0
    # between the two: 10% shorter than own is 0.4 of the weight ((30/27 - 1) / 0.25 = 0.44)
    sel.mean_length[1] = 27.0
    assert sel.credit_factors()[1] == pytest.approx((30 / 27 - 1) / 0.25)
    plain, late_plain = drive(credit=False)
    assert stats.chisquare(late_plain).pvalue > 1e-3  # equal shares without the rule
    assert "credit" not in plain.card()


def test_credit_puts_experts_on_probation_before_ppo_learns_from_them():
    """credit=True: PPO learns (policy-loss weight) from an expert's episodes only once it and
    the agents' own episodes have CREDIT_MIN_EPISODES judged episodes each, and then by its
    credit factor; own episodes always weigh 1. Without credit there are no weights."""
    length = {-1: 30, 0: 20, 1: 90}  # own, good, faulty
    experts = [FixedExpert(np.zeros((1, 1, 5)), n) for n in ("good", "faulty")]
    sel = DemonstrationSelector(experts, rate=0.5, seed=3, credit=True)
    ids = np.arange(8)
    sel.episode_start(ids)
    first = sel.sample_weights(8)
    assert (first[sel.current[ids] >= 0] == 0).all()  # nobody judged yet: probation
    assert (first[sel.current[ids] < 0] == 1).all()
    for _ in range(40):
        sel.steps_in_episode[ids] = [length[int(g)] for g in sel.current[ids]]
        sel.episode_start(ids)
    assert (sel.judged >= 4).all()
    np.testing.assert_array_equal(sel.learning_weights(), [1.0, 0.0])
    w = sel.sample_weights(8)
    expected = np.append(sel.learning_weights(), 1.0)[sel.current[ids]]
    np.testing.assert_array_equal(w, expected)
    assert sel.card()["experts"][1]["learning_weight"] == 0.0
    again = DemonstrationSelector(experts, rate=0.5, seed=3, credit=True)
    again.load_state_dict(json.loads(json.dumps(sel.state_dict())))
    np.testing.assert_array_equal(again.sample_weights(8), w)
    plain = DemonstrationSelector(experts, rate=0.5, seed=3)
    plain.episode_start(ids)
    assert plain.sample_weights(8) is None


def test_guided_steps_on_probation_do_not_move_the_policy():
    """Through Trainer: with every episode guided by an expert still on probation, the policy
    loss is 0 and the actor does not change (only the critic and entropy terms act, and with
    ent_coef 0 the actor keeps its weights); without the credit rule the same run moves it."""
    obs = ObservationSpec(kind="odmtl")
    ppo = PPOConfig(**{**TINY_PPO.to_dict(), "ent_coef": 0.0})

    def actor_after(credit):
        sel = DemonstrationSelector(load_experts(["biased:1"], TASK), rate=1.0, seed=0,
                                    credit=credit)
        trainer = Trainer(TASK, obs, ppo, tiny_run(updates=1), selector=sel)
        before = [p.detach().clone() for p in trainer.agent.actor.parameters()]
        trainer.train()
        after = list(trainer.agent.actor.parameters())
        return max((a - b).abs().max().item() for a, b in zip(after, before, strict=True))

    assert actor_after(credit=True) == 0.0
    assert actor_after(credit=False) > 0.0


def test_credit_counts_steps_through_the_trainer():
    """Wired through Trainer: select() counts steps, episode_start() folds finished episodes,
    and the run's card reports the running means; the config round-trips through the
    checkpoint's selector state."""
    obs = ObservationSpec(kind="odmtl")
    sel = DemonstrationSelector(load_experts(["oracle", "random"], TASK), rate=0.5, seed=0,
                                credit=True)
    Trainer(TASK, obs, TINY_PPO, tiny_run(updates=6), selector=sel).train()
    assert sel.judged.sum() > 0 and (sel.mean_length[sel.judged > 0] > 0).all()
    assert sel.config.to_dict()["credit"] is True
    assert DemonstrationConfig.from_dict({"models": ["oracle"], "credit": True}).credit
    with pytest.raises(ValueError, match="credit"):
        DemonstrationConfig.from_dict({"models": ["oracle"], "credit": "yes"})


def test_defaults_follow_tables_4_1_and_5_3():
    one = DemonstrationConfig(("oracle",))
    assert (one.resolved_rate, one.threshold) == (0.2, 0.05)  # Table 4.1: E, l
    assert DemonstrationConfig(("oracle", "random")).resolved_rate == 0.1  # Table 5.3: R_E
    for bad in (dict(qos=(1.0,)), dict(qos=(0.0, 0.0)), dict(rate=1.5), dict(threshold=1.0)):
        with pytest.raises(ValueError):
            DemonstrationConfig(("oracle", "random"), **bad)


# ---------------------------------------------------------------------------- reproducibility


def test_rate_zero_is_plain_ppo_bit_for_bit():
    obs = ObservationSpec(kind="odmtl")

    def weights(selector):
        t = Trainer(TASK, obs, TINY_PPO, tiny_run(), selector=selector)
        t.train()
        return t.agent.state_dict(), t.env.pos.copy()

    plain, pos = weights(None)
    off, pos_off = weights(DemonstrationSelector(load_experts(["oracle"], TASK), rate=0.0))
    on, _ = weights(DemonstrationSelector(load_experts(["oracle"], TASK), rate=1.0))
    assert all(torch.equal(plain[k], off[k]) for k in plain)
    np.testing.assert_array_equal(pos, pos_off)
    assert not all(torch.equal(plain[k], on[k]) for k in plain)  # the expert does change it


def test_resume_with_a_selector_continues_identically(tmp_path):
    obs = ObservationSpec(kind="odmtl")
    refs = ["oracle", "random", "malicious:random"]  # random experts carry RNG state

    def selector():
        return DemonstrationSelector.from_config(
            DemonstrationConfig(tuple(refs), (2.0, 1.0, 1.0), rate=0.6), TASK, seed=0)

    straight = Trainer(TASK, obs, TINY_PPO, tiny_run(updates=4, eval_every=2),
                       out=tmp_path / "a", selector=selector())
    straight.train()
    split = Trainer(TASK, obs, TINY_PPO, tiny_run(updates=2, eval_every=2), out=tmp_path / "b",
                    selector=selector())
    split.train()
    _, _, meta = load_checkpoint(tmp_path / "b" / "checkpoint")
    resumed = Trainer.resume(tmp_path / "b", selector=resume_selector(meta),
                             run_overrides={"total_steps": 4 * TINY_PPO.batch_steps})
    resumed.train()
    for k, v in straight.agent.state_dict().items():
        assert torch.equal(v, resumed.agent.state_dict()[k]), k
    assert straight.selector.state_dict() == resumed.selector.state_dict()
    with open(tmp_path / "a" / "metrics.csv") as fa, open(tmp_path / "b" / "metrics.csv") as fb:
        drop = ("wall_time", "sps")
        ra = [{k: v for k, v in r.items() if k not in drop} for r in csv.DictReader(fa)]
        rb = [{k: v for k, v in r.items() if k not in drop} for r in csv.DictReader(fb)]
    assert ra == rb
    card = load_model(tmp_path / "b" / "model").card["training"]["experts"]
    assert [e["ref"] for e in card["experts"]] == refs
    assert [e["qos"] for e in card["experts"]] == [2.0, 1.0, 1.0]
    used = [e["episodes"] for e in card["experts"]]
    assert sum(used) > 0 and card["own_episodes"] > 0
    with pytest.raises(ValueError, match="differ"):
        other = DemonstrationSelector(load_experts(["oracle"], TASK))
        other.load_state_dict(meta["selector"])


# ---------------------------------------------------------------------------- experts


def test_oracle_expert_ranks_the_oracle_policys_action_first():
    env = TargetLocalizationEnv(TASK, 32, seed=1)
    oracle, rng = load_expert("oracle", TASK), np.random.default_rng(1)
    for _ in range(30):
        s = oracle.scores(env, None)
        np.testing.assert_array_equal(s.argmax(-1), OraclePolicy().act(env))
        assert (np.isfinite(s) == env.action_mask()).all()
        m = env.action_mask()
        r = rng.random(m.shape)
        r[~m] = -1
        env.step(r.argmax(-1))


def test_faulty_experts_behave_as_specified_and_respect_the_mask():
    env = stepped_env(envs=64)
    mask = env.action_mask()
    valid = mask.sum(-1)
    rows = np.arange(64)
    rnd = load_expert("random", TASK, seed=0)
    tops = np.stack([rnd.scores(env, rows).argmax(-1) for _ in range(200)])  # (200, B, N)
    assert (np.take_along_axis(mask[None], tops[..., None], -1)).all()
    # uniform over the valid actions: the top choice of each agent hits all of them evenly
    for b, i in [(0, 0), (5, 1), (9, 2)]:
        counts = np.bincount(tops[:, b, i], minlength=5)[mask[b, i]]
        assert len(counts) == valid[b, i] and stats.chisquare(counts).pvalue > 1e-3
    biased = load_expert("biased:2", TASK).scores(env, rows)
    assert (np.isfinite(biased) == mask).all()
    assert (biased.argmax(-1)[mask[..., 2]] == 2).all()
    good = load_expert("oracle", TASK).scores(env, rows)
    bad = load_expert("malicious:oracle", TASK).scores(env, rows)
    assert (np.isfinite(bad) == mask).all()
    worst = np.where(mask, good, np.inf).argmin(-1)
    np.testing.assert_array_equal(bad.argmax(-1), worst)
    # a malicious expert makes the oracle's walker step away from the target
    b = np.arange(64)
    walker = np.argmin(env.dist[b[:, None], env.pos], 1)
    nxt = env.next_cell[b, env.pos[b, walker], bad.argmax(-1)[b, walker]]
    assert (env.dist[b, nxt] >= env.dist[b, env.pos[b, walker]]).all()


def test_bad_expert_references_are_named():
    with pytest.raises(ExpertError, match="biased"):
        load_expert("biased:7", TASK)  # 5 actions
    with pytest.raises(ExpertError, match="not a model directory"):
        load_expert("no/such/model", TASK)
    with pytest.raises(ExpertError, match="action index"):
        load_expert("biased:x", TASK)


def test_an_expert_card_without_its_input_shape_is_named(tmp_path):
    """The adapter checks what it builds against the card's actor_shape: a card without it is
    an ExpertError naming the field (was a KeyError traceback, or on resume 'incomplete
    checkpoint')."""
    import shutil
    from pathlib import Path

    zoo = Path(__file__).resolve().parents[2] / "models" / "odmtl-1a"
    expert = tmp_path / "expert"
    shutil.copytree(zoo, expert)
    card = json.loads((expert / "model.json").read_text())
    assert load_expert(str(expert), TASK).name == str(expert)
    del card["observation"]["actor_shape"]
    (expert / "model.json").write_text(json.dumps(card))
    with pytest.raises(ExpertError, match="observation.actor_shape"):
        load_expert(str(expert), TASK)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """Small saved models (one update of training each): the expert zoo of these tests."""
    root = tmp_path_factory.mktemp("zoo")
    made = {}
    for name, env, kind in [
        ("odmtl-1a-6x6", EnvSpec(rows=6, cols=6, agents=1), "odmtl"),
        ("odmtl-2a-10x10", EnvSpec(rows=10, cols=10, agents=2), "odmtl"),
        ("dmtl-1a-10x10", EnvSpec(rows=10, cols=10, agents=1), "dmtl"),
        ("cmtl-2a-6x6", EnvSpec(rows=6, cols=6, agents=2), "cmtl"),
    ]:
        t = Trainer(env, ObservationSpec(kind=kind), TINY_PPO, tiny_run(updates=1), out=None)
        t.train()
        made[name] = t.save_model(root / name)
    return made


def test_single_agent_expert_ranks_each_agent_of_a_team(models):
    expert = load_expert(str(models["odmtl-1a-6x6"]), TASK)
    env = stepped_env(envs=8)
    rows = np.array([1, 4, 6])
    got = expert.scores(env, rows)
    assert got.shape == (3, 3, 5)
    assert (np.isfinite(got) == env.action_mask()[rows]).all()
    policy = load_model(models["odmtl-1a-6x6"])
    for k in range(3):  # the expert sees task agent k as its only agent
        view = _OneAgent(EnvRows(env, rows), k)
        ok = np.isfinite(got[:, k])
        want = np.log(np.where(ok, policy.action_probs(view)[:, 0], 1.0))
        np.testing.assert_allclose(got[:, k][ok], want[ok], rtol=1e-5, atol=1e-6)


class _OneAgent:
    """Agent k of a team, alone (what a 1-agent expert should see)."""

    def __init__(self, env, k):
        self.env, self.k = env, k
        self.pos, self.readings = env.pos[:, [k]], env.readings
        self.visits, self.walls = env.visits, env.walls

    def past_pos(self, j):
        return self.env.past_pos(j)[:, [self.k]]

    def action_mask(self):
        return self.env.action_mask()[:, [self.k]]


def test_odmtl_expert_from_another_grid_and_team_size(models):
    task = EnvSpec(rows=12, cols=12, agents=3)
    expert = load_expert(str(models["odmtl-2a-10x10"]), task)
    env = stepped_env(task, envs=8)
    s = expert.scores(env, np.arange(8))
    assert s.shape == (8, 3, 5) and (np.isfinite(s) == env.action_mask()).all()
    np.testing.assert_allclose(np.exp(s).sum(-1), 1.0, rtol=1e-5)  # a proper distribution
    # the two other agents are merged into its "others" map: moving them changes the ranking
    moved = stepped_env(task, envs=8)  # the same state (same seed) ...
    np.testing.assert_array_equal(expert.scores(moved, np.arange(8)), s)
    moved.pos[:, 1:] = moved.pos[::-1, 1:]  # ... with agents 1, 2 elsewhere
    assert not np.allclose(expert.scores(moved, np.arange(8))[:, 0], s[:, 0])


def test_adapters_refuse_what_they_cannot_serve(models):
    with pytest.raises(ExpertError, match="full 10x10 maps"):
        load_expert(str(models["dmtl-1a-10x10"]), EnvSpec(rows=12, cols=12, agents=3))
    with pytest.raises(ExpertError, match="joint actions of exactly 2"):
        load_expert(str(models["cmtl-2a-6x6"]), TASK)
    t = Trainer(EnvSpec(rows=10, cols=10, agents=1), ObservationSpec(kind="odmtl", window=5),
                TINY_PPO, tiny_run(updates=1))
    w5 = t.save_model(models["cmtl-2a-6x6"].parent / "w5")
    # a window as large as the task's grid or larger still serves (windows pad off-grid
    # cells, the downsized maps are interpolated up), while a learner keeps w < min(rows, cols)
    small = EnvSpec(rows=4, cols=5, agents=2)
    expert = load_expert(str(w5), small)
    env = stepped_env(small, envs=6)
    s = expert.scores(env, np.arange(6))
    assert s.shape == (6, 2, 5) and (np.isfinite(s) == env.action_mask()).all()
    np.testing.assert_allclose(np.exp(s).sum(-1), 1.0, rtol=1e-5)
    actor, _ = expert.observer.observe(env)
    assert actor.shape[-2:] == (5, 5) and np.isfinite(actor).all()
    with pytest.raises(ValueError, match="window must satisfy"):
        make_observer(small, ObservationSpec(kind="odmtl", window=5))
    # a CMTL expert with the task's team ranks by its joint policy's marginals
    s = load_expert(str(models["cmtl-2a-6x6"]), EnvSpec(rows=6, cols=6, agents=2)).scores(
        stepped_env(EnvSpec(rows=6, cols=6, agents=2), envs=4), np.arange(4))
    np.testing.assert_allclose(np.exp(s).sum(-1), 1.0, rtol=1e-5)


def test_an_expert_whose_team_does_not_fit_the_task_grid_is_refused():
    """The adapter lays the expert's env on the task's grid with the expert's own team (its
    actor's channels): 10 agents and a target do not fit 3 x 3. ``expert_misfit``, the check
    a worker and the gateway run on the card alone, names it, and loading the expert raises
    the ExpertError a run reports, not a bare ValueError from deep in the observer."""
    from workers.mdrl.experts import expert_misfit

    path = "models/odmtl-10a"  # ODMTL: serves any grid, as long as its team fits on it
    exp = load_model(path).env_spec
    small = EnvSpec(rows=3, cols=3, agents=2)
    why = expert_misfit(exp, "odmtl", False, small)
    assert why is not None and "laid on the task's 3x3 grid" in why
    assert "10 agents and a target do not fit on 3x3" in why
    with pytest.raises(ExpertError, match="10 agents and a target do not fit on 3x3"):
        load_expert(path, small)
    assert expert_misfit(exp, "odmtl", False, EnvSpec(rows=4, cols=4, agents=2)) is None
    assert load_expert(path, EnvSpec(rows=4, cols=4, agents=2)).scores(
        stepped_env(EnvSpec(rows=4, cols=4, agents=2), envs=2), np.arange(2)).shape == (2, 2, 5)


def test_moves_are_matched_by_direction():
    four_on_eight = action_map(4, 8)  # idle, up, down, left, right -> idle, N, S, W, E
    assert four_on_eight.tolist() == [0, 3, 7, 5, 1]
    eight_on_four = action_map(8, 4)
    assert eight_on_four.tolist() == [0, 4, -1, 1, -1, 3, -1, 2, -1]


# ---------------------------------------------------------------------------- learning


@pytest.mark.benchmark  # 8 training runs: a learning-speed claim, make test-benchmarks
def test_dc_with_the_oracle_learns_faster_than_plain_ppo():
    """Sparse reward (Eq. 9), 8x8, 2 agents, 16k steps: with DC (rate 0.5) the greedy policy
    finds the target far more often. Measured (200 held-out episodes each, binomial s.e.
    ~0.035), seeds 0-3: plain 0.465 / 0.15 / 0.145 / 0.15, DC 0.395 / 0.645 / 0.405 / 0.565;
    a plain run sometimes gets lucky (seed 0), so the claim is on most seeds and the mean."""
    spec = EnvSpec(rows=8, cols=8, agents=2, reward="sparse", max_steps=40)
    ppo = PPOConfig(horizon=512, num_envs=32, update_epochs=4, num_minibatches=4,
                    learning_rate=1e-3, reward_scale=0.1)
    gains = []
    for seed in (0, 1, 2, 3):
        run = RunConfig(seed=seed, total_steps=16384, eval_every=0, eval_episodes=200,
                        checkpoint_every=0, progress=False, tensorboard=False)
        success = []
        for experts in (None, ["oracle"]):
            sel = (DemonstrationSelector(load_experts(experts, spec), rate=0.5, seed=seed)
                   if experts else None)
            t = Trainer(spec, ObservationSpec(kind="odmtl"), ppo, run, selector=sel)
            t.train()
            success.append(t.last_eval["eval_success"])
        gains.append(success[1] - success[0])
    assert sum(g > 0.1 for g in gains) >= 3 and np.mean(gains) > 0.15, gains


# ---------------------------------------------------------------------------- CLI and spec


def make_app():
    app = typer.Typer()
    app.command()(train)
    app.command("noop")(lambda: None)
    return app


def test_train_command_with_experts_lists_them_on_the_card(tmp_path):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text('preset = "odmtl-2a-10x10"\n[env]\nrows = 6\ncols = 6\n'
                   '[ppo]\nhorizon = 128\nnum_envs = 16\nupdate_epochs = 1\n'
                   '[run]\neval_episodes = 10\neval_every = 1\n'
                   '[experts]\nmodels = ["random"]\nthreshold = 0.1\n')
    out = tmp_path / "run"
    runner = CliRunner()
    args = ["train", "--config", str(cfg), "--steps", "256", "--seed", "5", "--out", str(out),
            "--no-progress", "--no-tensorboard", "--expert-credit", "--experts", "oracle,biased:1",
            "--expert-qos", "3,1", "--expert-rate", "0.5"]
    res = runner.invoke(make_app(), args)
    assert res.exit_code == 0, res.output
    card = json.loads((out / "model" / "model.json").read_text())["training"]["experts"]
    assert card["method"].startswith("MEDC") and card["rate"] == 0.5
    assert card["threshold"] == 0.1  # from the config file's section
    assert [(e["ref"], e["qos"]) for e in card["experts"]] == [("oracle", 3.0), ("biased:1", 1.0)]
    assert sum(e["episodes"] for e in card["experts"]) > 0
    assert "own_mean_length" in card["credit"] and "credit" in card["experts"][0]
    res = runner.invoke(make_app(), ["train", "--resume", str(out), "--steps", "384",
                                     "--no-progress", "--no-tensorboard"])
    assert res.exit_code == 0, res.output
    again = json.loads((out / "model" / "model.json").read_text())["training"]["experts"]
    assert again["own_episodes"] > card["own_episodes"] and "credit" in again  # resumed as run
    bad = runner.invoke(make_app(), args[:-4] + ["--expert-qos", "1", "--out", str(tmp_path / "x")])
    assert bad.exit_code != 0 and "qos" in bad.output
    scheduled = runner.invoke(make_app(), args + ["--expert-rate-end", "0", "--out",
                                                  str(tmp_path / "y")])
    assert scheduled.exit_code == 0, scheduled.output
    card = json.loads((tmp_path / "y" / "model" / "model.json").read_text())["training"]["experts"]
    assert (card["rate_start"], card["rate_end"]) == (0.5, 0.0) and card["rate"] < 0.5
    alone = runner.invoke(make_app(), ["train", "--preset", "odmtl-2a-10x10", "--steps", "10",
                                       "--expert-rate-end", "0", "--out", str(tmp_path / "z")])
    assert alone.exit_code != 0 and "--expert-rate-end" in alone.output


def test_task_spec_carries_experts_with_qos_and_settings():
    doc = {"env": {"rows": 6, "cols": 6, "agents": 3}, "budget": {"steps": 2000},
           "experts": ["models/a1w0", {"model": "QmYwAPJzv5CZsnA625s3Xf2nemtYgPpHdWEz79ojWnPbdG",
                                       "qos": 0.5}],
           "algorithm": {"demonstration": {"rate": 0.25}}}
    spec = TrainingSpec.from_dict(doc)
    assert spec.experts[1].startswith("Qm") and spec.expert_qos == (1.0, 0.5)
    assert TrainingSpec.from_dict(spec.to_dict()) == spec
    demo = spec.demonstration()
    assert demo.resolved_rate == 0.25 and demo.weights == (1.0, 0.5) and demo.threshold == 0.05
    schema = trainingspec_json_schema()
    import jsonschema_rs

    assert jsonschema_rs.Draft202012Validator(schema).is_valid(spec.to_dict())
    assert not demo.credit
    credited = TrainingSpec.from_dict({**doc, "algorithm": {"demonstration": {"credit": True}}})
    assert credited.demonstration().credit
    assert TrainingSpec.from_dict(credited.to_dict()) == credited
    plain = TrainingSpec.from_dict({**doc, "experts": ["a"], "algorithm": {}})
    assert plain.to_dict()["experts"] == ["a"] and plain.demonstration().resolved_rate == 0.2
    for change, field in [
        ({"experts": [{"model": "a", "qos": -1}]}, "experts[0].qos"),
        ({"experts": [{"qos": 1}]}, "experts[0].model"),
        ({"experts": [{"model": "a", "qos": 0}]}, "experts"),
        ({"algorithm": {"demonstration": {"threshold": 1.5}}}, "algorithm.demonstration.threshold"),
        ({"experts": [], "algorithm": {"demonstration": {"rate": 0.1}}}, "algorithm.demonstration"),
        ({"algorithm": {"demonstration": {"credit": "yes"}}}, "algorithm.demonstration.credit"),
    ]:
        with pytest.raises(SpecError) as info:
            TrainingSpec.from_dict({**doc, **change})
        assert info.value.field == field


def test_resume_refuses_an_expert_whose_model_was_swapped(tmp_path):
    """A model expert's weights digest goes on the card and into the checkpoint: a resumed run
    whose expert path now holds another model stops with a usage error (it would otherwise go
    on learning from a model the card does not name)."""
    import shutil
    from pathlib import Path

    zoo = Path(__file__).resolve().parents[2] / "models"
    expert = tmp_path / "expert"
    shutil.copytree(zoo / "odmtl-1a", expert)
    cfg = tmp_path / "tiny.toml"
    cfg.write_text('preset = "odmtl-2a-10x10"\n[env]\nrows = 6\ncols = 6\n'
                   '[ppo]\nhorizon = 64\nnum_envs = 8\nupdate_epochs = 1\n'
                   '[run]\neval_episodes = 4\neval_every = 0\n')
    out = tmp_path / "run"
    runner = CliRunner()
    res = runner.invoke(make_app(), ["train", "--config", str(cfg), "--steps", "128",
                                     "--out", str(out), "--no-progress", "--no-tensorboard",
                                     "--experts", str(expert)])
    assert res.exit_code == 0, res.output
    listed = json.loads((out / "model" / "model.json").read_text())["training"]["experts"]
    assert listed["experts"][0]["digest"].startswith("sha256:")
    resume = ["train", "--resume", str(out), "--steps", "192", "--no-progress",
              "--no-tensorboard"]
    shutil.rmtree(expert)
    shutil.copytree(zoo / "odmtl-2a", expert)  # same kind and inputs, other weights
    res = runner.invoke(make_app(), resume)
    said = " ".join(res.output.replace("│", " ").split())
    assert res.exit_code == 2 and "not the model this run learned from" in said, res.output
    shutil.rmtree(expert)
    shutil.copytree(zoo / "odmtl-1a", expert)  # the original back: the run goes on
    res = runner.invoke(make_app(), resume)
    assert res.exit_code == 0, res.output
