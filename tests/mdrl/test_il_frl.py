"""The MEDC benchmarks: IL-assisted RL (il.py) and federated RL (frl.py)."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
import torch

from workers.mdrl.experts import OracleExpert, RandomExpert, load_expert
from workers.mdrl.frl import HEAD, FederatedTrainer, poisoned_model
from workers.mdrl.il import ImitationTrainer, _expert_diff, expert_identity
from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.spec import EnvSpec
from workers.mdrl.train import TIMING_COLUMNS, RunConfig, Trainer

SMALL_PPO = PPOConfig(num_envs=32, horizon=512, update_epochs=4, num_minibatches=2,
                      learning_rate=3e-3, anneal_lr=False)


def _run(steps: int, **kw) -> RunConfig:
    kw = {"seed": 0, "eval_every": 0, "checkpoint_every": 0, **kw}
    return RunConfig(total_steps=steps, eval_episodes=20, tensorboard=False, progress=False, **kw)


def _oracle_agreement(trainer, env_spec: EnvSpec, batch: int = 64) -> float:
    """Share of agent decisions where the actor's greedy action is the oracle's first choice."""
    from workers.mdrl.env import TargetLocalizationEnv

    env = TargetLocalizationEnv(env_spec, batch, seed=123)
    actor, _ = trainer.observer.observe(env)
    mask = torch.from_numpy(trainer.head.policy_mask(env.action_mask()))
    n = mask.shape[1]
    with torch.no_grad():
        logits = trainer.agent.logits(torch.as_tensor(actor).reshape(batch * n, *actor.shape[2:]),
                                      mask.reshape(batch * n, -1))
    mine = logits.argmax(-1).reshape(batch, n).numpy()
    best = OracleExpert().scores(env, None).argmax(-1)
    return float((mine == best).mean())


def test_imitation_stages_clone_the_expert(tmp_path):
    """With only imitation stages, behaviour cloning of the oracle drives the cross-entropy
    down and the actor's greedy actions towards the oracle's first choices."""
    env = EnvSpec(rows=6, cols=6, agents=2)
    obs = ObservationSpec(kind="odmtl", window=3)
    trainer = ImitationTrainer(env, obs, SMALL_PPO, _run(24 * 512), out=tmp_path,
                               experts=[OracleExpert()], il_share=1.0)
    before = _oracle_agreement(trainer, env)
    trainer.train()
    after = _oracle_agreement(trainer, env)
    assert trainer.imitation_updates == trainer.update_idx == 24
    with (tmp_path / "metrics.csv").open() as f:
        ce = [float(r["policy_loss"]) for r in csv.DictReader(f)]
    assert ce[-1] < 0.7 * ce[0], ce
    assert after > before + 0.1, (before, after)


def test_imitation_is_every_fifth_update_and_recorded(tmp_path):
    env = EnvSpec(rows=6, cols=6, agents=2)
    obs = ObservationSpec(kind="odmtl", window=3)
    ppo = PPOConfig(num_envs=16, horizon=256, update_epochs=1, num_minibatches=1)
    trainer = ImitationTrainer(env, obs, ppo, _run(10 * 256), out=tmp_path,
                               experts=[OracleExpert()], il_share=0.2)
    trainer.train()
    with (tmp_path / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    imitation = [int(r["update"]) for r in rows if r["approx_kl"] == ""]
    assert len(rows) == 10 and imitation == [5, 10]  # updates 5 and 10 (1-based) cloned
    card = json.loads((tmp_path / "model" / "model.json").read_text())
    assert card["training"]["method"]["imitation_updates"] == 2
    assert card["training"]["method"]["experts"][0]["ref"] == "oracle"


def test_imitation_rejects_bad_settings():
    env, obs = EnvSpec(rows=6, cols=6), ObservationSpec(kind="odmtl", window=3)
    with pytest.raises(ValueError, match="il_share"):
        ImitationTrainer(env, obs, SMALL_PPO, _run(100), experts=[OracleExpert()], il_share=0)
    with pytest.raises(ValueError, match="at least one expert"):
        ImitationTrainer(env, obs, SMALL_PPO, _run(100), experts=[])


USERS = [("A1W0", EnvSpec(rows=8, cols=8, agents=1, moves=8)),
         ("A2W1", EnvSpec(rows=8, cols=8, agents=2, moves=8, walls=(1, 1))),
         ("A3W1", EnvSpec(rows=8, cols=8, agents=3, moves=8, walls=(1, 1)))]


def test_fedavg_gives_every_user_the_mean_of_their_weights():
    obs = ObservationSpec(kind="odmtl", window=3)
    frl = FederatedTrainer(USERS, obs, SMALL_PPO, _run(1000), target="A3W1")
    # the users start from one global model even though their seeds differ
    first = [t.agent.state_dict() for t in frl.trainers.values()]
    for k in first[0]:
        assert all(torch.equal(first[0][k], s[k]) for s in first[1:])
    with torch.no_grad():
        for i, t in enumerate(frl.trainers.values()):
            for p in t.agent.parameters():
                p.add_(float(i + 1))  # user i drifts by i + 1
    before = {k: v.clone() for k, v in first[0].items()}  # user 0 after its drift
    frl.average()
    for t in frl.trainers.values():
        for k, v in t.agent.state_dict().items():
            # mean of (w + 1, w + 2, w + 3) = w + 2 = user 0's drifted weights + 1
            assert torch.allclose(v, before[k] + 1.0, atol=1e-5), k
    assert frl.rounds == 1


def test_frl_trains_and_reports_from_the_target(tmp_path):
    obs = ObservationSpec(kind="odmtl", window=3)
    frl = FederatedTrainer(USERS, obs, SMALL_PPO, _run(3 * 512, eval_every=1, keep_best="time"),
                           target="A2W1", out=tmp_path)
    frl.train()
    assert frl.global_step == 3 * 512
    assert all(t.global_step == 3 * 512 for t in frl.trainers.values())
    states = [t.agent.state_dict() for t in frl.trainers.values()]
    for k in states[0]:
        assert all(torch.equal(states[0][k], s[k]) for s in states[1:])  # averaged last
    with (tmp_path / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 and all(not math.isnan(float(r["eval_time"])) for r in rows)
    # RunConfig.keep_best: the global model of the round with the shortest evaluation time
    times = [(float(r["eval_time"]), float(r["eval_cost"])) for r in rows]
    assert frl.trainer.best["update"] == int(rows[times.index(min(times))]["update"])
    assert (tmp_path / "best" / "model.json").is_file()
    card = json.loads((tmp_path / "model" / "model.json").read_text())
    assert card["env"]["agents"] == 2 and card["training"]["method"]["rounds"] == 3
    assert card["training"]["method"]["env_steps_all_users"] == 3 * 3 * 512
    # every user sees walls and the others map: one input set, so one architecture
    assert card["observation"]["walls"] is True and card["observation"]["others"] is True


def test_frl_averaging_every_k_updates_ends_its_last_round_at_the_budget(tmp_path):
    """local_updates = 2 on a 3-update budget: a round of 2 updates, then one cut short after 1
    (not 4 updates, 1/3 past the budget), averaged; the finished run's checkpoint resumes."""
    obs = ObservationSpec(kind="odmtl", window=3)
    frl = FederatedTrainer(USERS, obs, SMALL_PPO, _run(3 * 512, eval_every=1),
                           target="A2W1", local_updates=2, out=tmp_path)
    frl.train()
    assert frl.rounds == 2 and frl.global_step == 3 * 512
    assert all(t.update_idx == 3 for t in frl.trainers.values())
    states = [t.agent.state_dict() for t in frl.trainers.values()]
    for k in states[0]:
        assert all(torch.equal(states[0][k], s[k]) for s in states[1:])  # averaged last
    with (tmp_path / "metrics.csv").open() as f:
        assert [int(r["update"]) for r in csv.DictReader(f)] == [2, 3]  # one row a round
    method = json.loads((tmp_path / "model" / "model.json").read_text())["training"]["method"]
    assert method["local_updates"] == 2 and method["rounds"] == 2
    again = FederatedTrainer.resume(tmp_path)
    assert (again.rounds, again.trainer.update_idx, again.local_updates) == (2, 3, 2)
    assert not again.budget_left()
    # 3 updates in rounds of 2 cannot be 1 round: a checkpoint saying so is refused
    meta = json.loads((tmp_path / "checkpoint" / "frl.json").read_text())
    (tmp_path / "checkpoint" / "frl.json").write_text(json.dumps({**meta, "rounds": 1}))
    with pytest.raises(ValueError, match="user A1W0 is at update 3, .* round 1 of 2 updates"):
        FederatedTrainer.resume(tmp_path)


def test_frl_refuses_users_it_cannot_average():
    obs = ObservationSpec(kind="odmtl", window=3)
    mixed = [*USERS, ("A1W0-4", EnvSpec(rows=8, cols=8, agents=1, moves=4))]
    with pytest.raises(ValueError, match="same move set"):
        FederatedTrainer(mixed, obs, SMALL_PPO, _run(100), target="A1W0")
    with pytest.raises(ValueError, match="target user"):
        FederatedTrainer(USERS, obs, SMALL_PPO, _run(100), target="A9W9")
    with pytest.raises(ValueError, match="distinct"):
        FederatedTrainer([USERS[0], USERS[0]], obs, SMALL_PPO, _run(100), target="A1W0")


def test_faulty_frl_users_send_poison_and_train_nothing():
    """Fig. 5.8 for FRL: a faulty user has no trainer; its share in the average is random
    weights, an actor that always picks one action, or the global actor's ranking reversed."""
    obs = ObservationSpec(kind="odmtl", window=3)
    for kind in ("random", "biased:4", "malicious"):
        frl = FederatedTrainer(USERS, obs, SMALL_PPO, _run(1000), target="A3W1",
                               faulty={"A1W0": kind})
        assert list(frl.trainers) == ["A2W1", "A3W1"]  # the faulty user trains nothing
        g = {k: v.clone() for k, v in frl.global_model.items()}
        poison = poisoned_model(kind, g, torch.Generator().manual_seed(0))
        w, b = poison[f"{HEAD}.weight"], poison[f"{HEAD}.bias"]
        x = torch.randn(5, w.shape[1])
        good = x @ g[f"{HEAD}.weight"].T + g[f"{HEAD}.bias"]
        if kind == "malicious":  # the good head's ranking, reversed
            assert torch.equal((x @ w.T + b).argsort(-1), good.argsort(-1).flip(-1))
        elif kind == "biased:4":
            assert ((x @ w.T + b).argmax(-1) == 4).all()
            assert torch.equal(poison["critic.net.10.bias"], g["critic.net.10.bias"])
        else:  # random: every float tensor replaced, at the global tensor's scale
            for k, v in g.items():
                assert not torch.equal(poison[k], v), k
            std = g["actor.net.0.weight"].std()
            assert 0.5 < float(poison["actor.net.0.weight"].std() / std) < 2.0
        frl.average()  # the honest users get the mean of their 2 models and the poison
        honest = [t.agent.state_dict() for t in frl.trainers.values()]
        head = honest[0][f"{HEAD}.weight"]
        if kind == "malicious":  # (g + g - g) / 3
            assert torch.allclose(head, g[f"{HEAD}.weight"] / 3, atol=1e-6)
        elif kind == "biased:4":  # (g + g + 0) / 3, and a third of the biased logit
            assert torch.allclose(head, 2 * g[f"{HEAD}.weight"] / 3, atol=1e-6)
            assert abs(float(honest[0][f"{HEAD}.bias"][4]) - 10 / 3) < 1e-5
        else:
            assert not torch.allclose(head, g[f"{HEAD}.weight"], atol=1e-4)
        assert all(torch.equal(honest[0][k], honest[1][k]) for k in honest[0])


def test_faulty_frl_users_are_checked():
    obs = ObservationSpec(kind="odmtl", window=3)
    with pytest.raises(ValueError, match="other than the target"):
        FederatedTrainer(USERS, obs, SMALL_PPO, _run(100), target="A3W1",
                         faulty={"A3W1": "random"})
    with pytest.raises(ValueError, match="other than the target"):
        FederatedTrainer(USERS, obs, SMALL_PPO, _run(100), target="A3W1",
                         faulty={"A9W9": "random"})
    for bad, match in (("lazy", "unknown faulty"), ("random:3", "unknown faulty"),
                       ("biased:x", "integer"), ("biased:9", "not one of 0..8")):
        with pytest.raises(ValueError, match=match):
            FederatedTrainer(USERS, obs, SMALL_PPO, _run(100), target="A3W1",
                             faulty={"A1W0": bad})


def test_frl_run_with_a_faulty_user_resumes_as_the_uninterrupted_run(tmp_path):
    """The poison's random stream is in the checkpoint: a killed run with a random user ends
    with the weights of a run never interrupted."""
    def run(out, crash_at=None):
        obs = ObservationSpec(kind="odmtl", window=3)
        frl = FederatedTrainer(USERS, obs, TINY_PPO,
                               _run(4 * TINY_PPO.batch_steps, checkpoint_every=2),
                               target="A2W1", out=out, faulty={"A3W1": "random"})
        _train(frl, frl.trainer, crash_at)
        return frl

    straight = run(tmp_path / "straight")
    run(tmp_path / "split", crash_at=3)
    resumed = FederatedTrainer.resume(tmp_path / "split")
    assert resumed.faulty == {"A3W1": "random"} and list(resumed.trainers) == ["A1W0", "A2W1"]
    resumed.train()
    for k, v in straight.global_model.items():
        assert torch.equal(v, resumed.global_model[k]), k
    card = json.loads((tmp_path / "split" / "model" / "model.json").read_text())
    assert card["training"]["method"]["faulty_users"] == {"A3W1": "random"}


def test_frl_budget_is_required():
    obs = ObservationSpec(kind="odmtl", window=3)
    frl = FederatedTrainer(USERS[:1], obs, SMALL_PPO,
                           RunConfig(progress=False, tensorboard=False), target="A1W0")
    with pytest.raises(ValueError, match="budget"):
        frl.train()
    assert np.isfinite(frl.elapsed)


# ---------------------------------------------------------------------------- resuming
TINY_PPO = PPOConfig(num_envs=8, horizon=64, update_epochs=2, num_minibatches=2,
                     learning_rate=3e-3)  # T = 8 steps per update


class Crash(Exception):
    """Stands for the process being killed."""


def _train(run, trainer, crash_at: int | None) -> None:
    """``run.train()``; with ``crash_at``, ``trainer`` dies when it starts collecting that
    update (0-based) and the run stops with ``Crash``."""
    if crash_at is None:
        run.train()
        return
    real = trainer.collect

    def collect():
        if trainer.update_idx == crash_at:
            raise Crash
        return real()

    trainer.collect = collect
    with pytest.raises(Crash):
        run.train()


def _metrics(path):
    with (path / "metrics.csv").open() as f:
        return [{k: v for k, v in r.items() if k not in TIMING_COLUMNS}
                for r in csv.DictReader(f)]


def _il_experts():
    return [OracleExpert(), RandomExpert(seed=5)]


def _il_run(out, crash_at=None):
    env, obs = EnvSpec(rows=6, cols=6, agents=2), ObservationSpec(kind="odmtl", window=3)
    run = _run(6 * TINY_PPO.batch_steps, checkpoint_every=2)
    trainer = ImitationTrainer(env, obs, TINY_PPO, run, out=out, experts=_il_experts(),
                               qos=[2.0, 1.0], il_share=0.5)
    _train(trainer, trainer, crash_at)
    return trainer


def test_il_run_resumed_after_a_crash_ends_as_the_uninterrupted_run(tmp_path):
    """Killed in update 4 of 6 (checkpoint after update 2, imitation every 2nd update, two
    experts on a roulette wheel): resumed, it ends with the same weights, imitator state and
    metrics as a run that was never interrupted."""
    straight = _il_run(tmp_path / "straight")
    _il_run(tmp_path / "split", crash_at=3)
    resumed = ImitationTrainer.resume(tmp_path / "split", experts=_il_experts(), qos=[2.0, 1.0])
    assert resumed.update_idx == 2 and resumed.imitation_updates == 1 and resumed.period == 2
    resumed.train()
    assert resumed.imitation_updates == straight.imitation_updates == 3
    for k, v in straight.agent.state_dict().items():
        assert torch.equal(v, resumed.agent.state_dict()[k]), k
    assert resumed.imitator.state_dict() == straight.imitator.state_dict()
    assert _metrics(tmp_path / "split") == _metrics(tmp_path / "straight")


def test_il_resume_refuses_other_experts(tmp_path):
    _il_run(tmp_path, crash_at=3)
    with pytest.raises(ValueError, match=r"2 expert\(s\) \['oracle', 'random'\], given 1"):
        ImitationTrainer.resume(tmp_path, experts=[OracleExpert()])
    with pytest.raises(ValueError, match="expert 1 ref: 'random' in the checkpoint, 'other'"):
        ImitationTrainer.resume(tmp_path, experts=[OracleExpert(), OracleExpert("other")],
                                qos=[2.0, 1.0])
    with pytest.raises(ValueError, match="expert 0 qos: 2.0 in the checkpoint, 1.0 given"):
        ImitationTrainer.resume(tmp_path, experts=_il_experts())  # equal QoS by default


def test_a_model_expert_is_identified_by_its_weights(tmp_path):
    """Another model saved at the same path is another expert."""
    env, obs = EnvSpec(rows=6, cols=6, agents=2), ObservationSpec(kind="odmtl", window=3)
    ids = []
    for seed in (0, 1):
        Trainer(env, obs, TINY_PPO, _run(64, seed=seed)).save_model(tmp_path / "m")
        ids.append(expert_identity(load_expert(str(tmp_path / "m"), env), 1.0))
    assert ids[0]["ref"] == ids[1]["ref"] and ids[0]["digest"] != ids[1]["digest"]
    assert [d.split(":")[0] for d in _expert_diff(ids[:1], ids[1:])] == ["expert 0 digest"]


def _frl_run(out, crash_at=None, rounds=4):
    obs = ObservationSpec(kind="odmtl", window=3)
    frl = FederatedTrainer(USERS, obs, TINY_PPO,
                           _run(rounds * TINY_PPO.batch_steps, checkpoint_every=2),
                           target="A2W1", out=out)
    _train(frl, frl.trainer, crash_at)  # the target is the 2nd user: A1W0 has collected
    return frl


def test_frl_run_resumed_after_a_crash_ends_as_the_uninterrupted_run(tmp_path):
    """Killed in round 4 of 4 (checkpoint after round 2): resumed, every user ends with the
    same weights, and the target with the same metrics, as a run never interrupted."""
    straight = _frl_run(tmp_path / "straight")
    _frl_run(tmp_path / "split", crash_at=3)
    assert sorted(p.name for p in (tmp_path / "split").iterdir() if "checkpoint" in p.name) == [
        "checkpoint"]
    resumed = FederatedTrainer.resume(tmp_path / "split")
    assert resumed.rounds == 2 and resumed.global_step == 2 * TINY_PPO.batch_steps
    resumed.train()
    assert resumed.rounds == straight.rounds == 4 and list(resumed.trainers) == list(
        straight.trainers)
    for name, t in straight.trainers.items():
        mine = resumed.trainers[name]
        assert mine.global_step == t.global_step
        for k, v in t.agent.state_dict().items():
            assert torch.equal(v, mine.agent.state_dict()[k]), (name, k)
    for k, v in straight.global_model.items():
        assert torch.equal(v, resumed.global_model[k]), k
    assert _metrics(tmp_path / "split") == _metrics(tmp_path / "straight")


def test_frl_resume_names_a_missing_or_corrupt_user_checkpoint(tmp_path):
    import shutil

    _frl_run(tmp_path / "run", rounds=1)
    ckpt = tmp_path / "run" / "checkpoint"
    FederatedTrainer.resume(ckpt)  # intact: loads
    shutil.copytree(ckpt, tmp_path / "missing")
    shutil.rmtree(tmp_path / "missing" / "users" / "A1W0")
    with pytest.raises(ValueError, match="user A1W0's checkpoint .* cannot be loaded"):
        FederatedTrainer.resume(tmp_path / "missing")
    shutil.copytree(ckpt, tmp_path / "corrupt")
    (tmp_path / "corrupt" / "users" / "A3W1" / "state.safetensors").write_bytes(b"\0" * 64)
    with pytest.raises(ValueError, match="user A3W1's checkpoint .* cannot be loaded"):
        FederatedTrainer.resume(tmp_path / "corrupt")
    (tmp_path / "corrupt" / "frl.json").unlink()
    with pytest.raises(ValueError, match="not a readable FRL checkpoint"):
        FederatedTrainer.resume(tmp_path / "corrupt")




def test_an_il_checkpoint_does_not_resume_as_plain_ppo(tmp_path):
    """Plain PPO would drop the IL stage's state: ``Trainer.resume`` refuses the checkpoint."""
    _il_run(tmp_path, crash_at=3)
    with pytest.raises(ValueError, match="ImitationTrainer run; resume it with ImitationTrainer"):
        Trainer.resume(tmp_path)
