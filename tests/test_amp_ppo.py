"""AMP discriminator and the AmpPPO extension of rsl-rl's PPO, on a point-mass VecEnv."""

from __future__ import annotations

import copy

import pytest
import torch
from rsl_rl.models import MLPModel
from rsl_rl.runners import OnPolicyRunner

from detach.config.schema import AmpCfg
from detach.train.discriminator import AmpDiscriminator, ReplayBuffer
from tests.fakes import PointMassEnv


class MultiHeadCritic(MLPModel):
    num_objectives = 2

    def __init__(self, obs, obs_groups, obs_set, output_dim, **kw):
        super().__init__(obs, obs_groups, obs_set, self.num_objectives, **kw)


def train_cfg(critic_class: str = "rsl_rl.models:MLPModel", amp: bool = True) -> dict:
    return {
        "num_steps_per_env": 8, "save_interval": 100, "check_for_nan": True,
        "obs_groups": {"actor": ["self", "env", "task"], "critic": ["critic", "task"]},
        "algorithm": {"class_name": "detach.train.amp_ppo:AmpPPO", "num_learning_epochs": 2,
                      "num_mini_batches": 2, "learning_rate": 1e-3,
                      "amp": AmpCfg(enabled=amp, task_reward_weight=0.5, style_reward_weight=0.5,
                                    disc_hidden=(32, 32), batch_size=64, replay_size=1000)},
        "actor": {"class_name": "rsl_rl.models:MLPModel", "hidden_dims": [32, 32],
                  "distribution_cfg": {"class_name": "rsl_rl.modules:GaussianDistribution",
                                       "init_std": 1.0}},
        "critic": {"class_name": critic_class, "hidden_dims": [32, 32]},
        "logger": {"class_name": "detach.train.null_writer:NullWriter"},
    }


def reference(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Reference motion: points resting near the origin."""
    pos = torch.randn(n, 2) * 0.05
    return torch.cat([pos, pos], -1), torch.nn.functional.one_hot(
        torch.zeros(n, dtype=torch.long), 4).float()


def test_discriminator_separatesreference_from_noise() -> None:
    torch.manual_seed(0)
    disc = AmpDiscriminator(20, cond_dim=0, hidden=(64, 64))
    opt = torch.optim.Adam(disc.parameters(), lr=1e-3)
    t = torch.linspace(0, 1, 10)

    def reference(n: int) -> torch.Tensor:
        phase = torch.rand(n, 1) * 6.28
        return torch.cat([torch.sin(6.28 * t + phase), torch.cos(6.28 * t + phase)], -1)

    for _ in range(300):
        ref, noise = reference(128), torch.randn(128, 20)
        terms = disc.loss(ref, noise)
        opt.zero_grad()
        terms["total"].backward()
        opt.step()
        disc.normalizer.update(torch.cat([ref, noise]))
    with torch.no_grad():
        ref_reward = disc.style_reward(reference(256)).mean()
        noise_reward = disc.style_reward(torch.randn(256, 20)).mean()
    assert terms["accuracy"] > 0.95
    assert ref_reward > 0.8 and ref_reward - noise_reward > 0.5


def test_replay_buffer_wraps_around() -> None:
    buf = ReplayBuffer(5, 2, 1, "cpu")
    buf.insert(torch.arange(8.0).reshape(4, 2), torch.ones(4, 1))
    buf.insert(torch.arange(8.0, 12.0).reshape(2, 2), torch.zeros(2, 1))
    assert buf.size == 5
    assert sorted(buf.obs[:, 0].tolist()) == [2.0, 4.0, 6.0, 8.0, 10.0]
    obs, cond = buf.sample(7)
    assert obs.shape == (7, 2) and cond.shape == (7, 1)


@pytest.mark.parametrize("critic", ["rsl_rl.models:MLPModel",
                                    f"{__name__}:MultiHeadCritic"])
def test_amp_ppo_trains_and_checkpoints(critic: str, tmp_path) -> None:
    torch.manual_seed(0)
    env = PointMassEnv()
    runner = OnPolicyRunner(env, train_cfg(critic), log_dir=None, device="cpu")
    alg = runner.alg
    alg.reference_sampler = reference
    assert alg.num_objectives == (2 if "MultiHead" in critic else 1)
    before = copy.deepcopy(alg.discriminators.state_dict())
    runner.learn(3)
    after = alg.discriminators.state_dict()
    assert any(not torch.equal(before[k], after[k]) for k in before), "discriminator trained"
    assert alg.replay.size > 0
    path = tmp_path / "model.pt"
    runner.save(str(path))
    fresh = OnPolicyRunner(PointMassEnv(), train_cfg(critic), log_dir=None, device="cpu")
    fresh.load(str(path))
    for k, v in alg.discriminators.state_dict().items():
        assert torch.equal(v, fresh.alg.discriminators.state_dict()[k])
    assert fresh.alg.disc_optimizer.state_dict()["state"].keys() == \
        alg.disc_optimizer.state_dict()["state"].keys()


def test_per_objective_advantages_are_normalised_separately() -> None:
    torch.manual_seed(0)
    env = PointMassEnv()
    runner = OnPolicyRunner(env, train_cfg(f"{__name__}:MultiHeadCritic"), None, "cpu")
    alg = runner.alg
    alg.reference_sampler = reference
    obs = env.get_observations()
    with torch.inference_mode():
        for _ in range(8):
            actions = alg.act(obs)
            obs, rew, dones, extras = env.step(actions)
            alg.process_env_step(obs, rew * 100.0, dones, extras)  # task reward on a huge scale
        alg.compute_returns(obs)
    st = alg.storage
    per_objective = (st.returns - st.values).reshape(-1, 2)
    normalised = (per_objective - per_objective.mean(0)) / (per_objective.std(0) + 1e-8)
    expected = (normalised * alg.objective_weights).sum(-1)
    assert torch.allclose(st.advantages.reshape(-1), expected, atol=1e-5)
    assert st.advantages.shape == (8, env.num_envs, 1)
