"""Networks of detach.models on random observations shaped like EXAMPLE_SPEC (small batches)."""

from __future__ import annotations

import dataclasses
import io

import pytest
import torch
import yaml
from rsl_rl.algorithms import PPO
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils import resolve_class
from tensordict import TensorDict

from detach.config.schema import ModelCfg
from detach.config.validate import to_plain
from detach.envs.obs_spec import EXAMPLE_SPEC, ObsSpec
from detach.models import DEFAULT_OBS_GROUPS, DetachModel, build_actor_critic, rsl_rl_model_cfgs
from detach.models import losses as L
from detach.models.cml import CMLCfg
from detach.models.detach_net import DetachCfg
from detach.models.fusion import MoEFusion
from detach.models.mlp import MLPCfg
from detach.models.tokenhsi import TokenHSICfg

SPEC = EXAMPLE_SPEC
CML_OBJECTIVES = ("task", "disc_upper", "disc_lower")
KINDS: dict[str, ModelCfg] = {
    "detach": DetachCfg(),
    "detach_shared": DetachCfg(shared_trunk=True),
    "ablation_a1": DetachCfg(use_env_encoder=False),
    "ablation_a2": DetachCfg(use_self_encoder=False),
    "tokenhsi": TokenHSICfg(num_heads=2, ff_dim=512),
    "cml": CMLCfg(critic_objectives=CML_OBJECTIVES),
    "mlp": MLPCfg(),
}


SMALL_SPEC = ObsSpec(
    self_steps=5, self_dim=24, env_steps=5, env_dim=12 + 25, height_map_cells=25, num_skills=4,
    critic_dim=32, amp_steps=2, amp_dim=8, num_actions=8,
)
"""A reduced spec for the training tests, so 200 optimiser steps stay cheap on 2 cores."""


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """One intra-op thread: faster than 2 on this machine, and robust to other processes (OpenMP spin-waits)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def random_obs(n: int, spec: ObsSpec = SPEC, seed: int = 0) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    return TensorDict({k: torch.randn(n, d, generator=g) for k, d in spec.group_dims().items()}, batch_size=[n])


def build(name: str, n: int = 8, spec: ObsSpec = SPEC):
    torch.manual_seed(0)
    obs = random_obs(n, spec)
    actor, critic = build_actor_critic(KINDS[name], spec, obs)
    return actor, critic, obs


def ppo_like_loss(actor, critic, obs: TensorDict) -> torch.Tensor:
    actions = actor(obs, stochastic_output=True).detach()
    return -actor.get_output_log_prob(actions).mean() + critic(obs).pow(2).mean()


def param_count(m: torch.nn.Module) -> int:
    return sum(p.numel() for p in m.parameters())


@pytest.mark.parametrize("name", list(KINDS))
def test_output_shapes(name: str) -> None:
    actor, critic, obs = build(name)
    n = obs.batch_size[0]
    assert actor(obs).shape == (n, SPEC.num_actions)
    sample = actor(obs, stochastic_output=True)
    assert sample.shape == (n, SPEC.num_actions)
    assert actor.get_output_log_prob(sample).shape == (n,)
    assert actor.output_entropy.shape == (n,)
    assert critic(obs).shape == (n, 1)
    if name == "cml":
        assert critic.value_heads(obs).shape == (n, len(CML_OBJECTIVES))
    print(f"{name}: actor {param_count(actor):,} params, critic {param_count(critic):,}")


@pytest.mark.parametrize("name", list(KINDS))
def test_gradients_reach_every_trainable_parameter(name: str) -> None:
    actor, critic, obs = build(name)
    loss = ppo_like_loss(actor, critic, obs)
    if isinstance(actor, DetachModel):
        loss = loss + sum(actor.aux_losses(obs, reuse_forward=True).values())
        if critic.owns_trunk:
            loss = loss + sum(critic.aux_losses(obs).values())
    loss.backward()
    for model in (actor, critic):
        missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
        assert not missing, f"no gradient: {missing}"


def test_policy_loss_alone_leaves_only_pretraining_heads_without_gradient() -> None:
    actor, critic, obs = build("detach")
    ppo_like_loss(actor, critic, obs).backward()
    heads = {id(p) for m in actor.trunk.pretrain_head_modules() for p in m.parameters()}
    for n, p in actor.named_parameters():
        assert (p.grad is None) == (id(p) in heads), n


def test_frozen_encoders_get_no_gradient_in_stage_2() -> None:
    actor, critic, obs = build("detach")
    actor.freeze_encoders()
    enc = list(actor.encoder_parameters())
    before = [p.detach().clone() for p in enc]
    opt = torch.optim.Adam(actor.parameters(), lr=1e-2)
    loss = ppo_like_loss(actor, critic, obs) + actor.aux_loss(obs, "fusion")
    loss.backward()
    assert all(p.grad is None for p in enc)
    assert all(p.grad is not None for p in actor.fusion_parameters())
    opt.step()
    assert all(torch.equal(a, b) for a, b in zip(before, enc))
    actor.unfreeze_encoders()
    actor.zero_grad()
    ppo_like_loss(actor, critic, obs).backward()
    assert all(p.grad is not None for p in actor.encoder_parameters())


def test_parameter_groups_partition_the_model() -> None:
    actor, _, _ = build("detach")
    groups = [
        list(actor.encoder_parameters()),
        [p for m in actor.trunk.pretrain_head_modules() for p in m.parameters()],
        list(actor.fusion_parameters()),
        list(actor.head_parameters()),
    ]
    ids = [id(p) for g in groups for p in g]
    assert len(ids) == len(set(ids))
    assert set(ids) == {id(p) for p in actor.parameters()}
    assert {id(p) for p in actor.pretrain_parameters()} == {id(p) for p in groups[0] + groups[1]}


@pytest.mark.parametrize(
    "ablation, removed",
    [
        ("ablation_a1", ("env_encoder.", "env_decoder.")),
        ("ablation_a2", ("self_encoder.", "self_decoder.", "predictor.")),
    ],
)
def test_ablation_removes_exactly_the_named_module(ablation: str, removed: tuple[str, ...]) -> None:
    full, _, _ = build("detach")
    abl, _, _ = build(ablation)
    names_full = {n: p.shape for n, p in full.trunk.named_parameters()}
    names_abl = {n: p.shape for n, p in abl.trunk.named_parameters()}
    gone = set(names_full) - set(names_abl)
    assert set(names_abl) <= set(names_full)
    assert gone == {n for n in names_full if n.startswith(removed)}
    changed = {n for n in names_abl if names_abl[n] != names_full[n]}
    proj = "proj_env" if ablation == "ablation_a1" else "proj_self"
    assert changed == {f"{proj}.weight"}  # now fed by raw frames
    modules = sorted({n.split(".")[0] for n in gone})
    print(f"detach {param_count(full):,} -> {ablation} {param_count(abl):,} params (removed {modules})")


def test_r_decouple_zero_for_constants_and_grows_with_correlation() -> None:
    g = torch.Generator().manual_seed(1)
    n = 4096
    const_a, const_b = torch.full((n, 8), 3.0), torch.full((n, 6), -1.0)
    assert L.r_decouple(const_a, const_b).item() == 0.0
    assert L.gaussian_mi(const_a, const_b).item() == 0.0
    a = torch.randn(n, 4, generator=g)
    noise = torch.randn(n, 4, generator=g)
    values, mis = [], []
    for rho in (0.0, 0.3, 0.6, 0.9):
        b = rho * a + (1 - rho**2) ** 0.5 * noise
        values.append(L.r_decouple(a, b).item())
        mis.append(L.gaussian_mi(a, b).item())
    assert values[0] < 0.01 and mis[0] < 0.01
    assert all(x < y for x, y in zip(values, values[1:])) and all(x < y for x, y in zip(mis, mis[1:]))
    # 4 diagonal correlations of 0.9 among 16 pairs: means over the pairs (the code width does
    # not scale the term, so λ acts the same at any width)
    assert values[-1] == pytest.approx(4 * 0.81 / 16, rel=0.05)
    assert mis[-1] == pytest.approx(-0.5 * 4 * torch.log(torch.tensor(1 - 0.81)).item() / 16, rel=0.1)


def test_moe_router_weights_sum_to_one() -> None:
    moe = MoEFusion(16, 4, (32, 16))
    f_env, f_self = torch.randn(5, 3, 16), torch.randn(5, 3, 16)
    out, w = moe(f_env, f_self)
    assert out.shape == (5, 3, 16) and w.shape == (5, 3, 4)
    assert torch.allclose(w.sum(-1), torch.ones(5, 3)) and (w >= 0).all()


def test_fusion_diversity_modes() -> None:
    f = torch.randn(4, 3, 8)
    assert L.fusion_diversity([f, f, f], "distance").item() == 0.0
    assert L.fusion_diversity([f, f, f], "cosine").item() == pytest.approx(1.0)
    assert L.fusion_diversity([f, -f, f + 1], "distance").item() > 0


@pytest.mark.parametrize("name", ["detach", "detach_shared", "tokenhsi", "cml"])
def test_state_dict_round_trip(name: str) -> None:
    actor, critic, obs = build(name)
    if isinstance(actor, DetachModel):
        actor.snapshot_encoders()
    buf = io.BytesIO()
    torch.save({"actor": actor.state_dict(), "critic": critic.state_dict()}, buf)
    torch.manual_seed(123)  # different initial weights
    actor2, critic2 = build_actor_critic(KINDS[name], SPEC, obs)
    assert not torch.allclose(actor2(obs), actor(obs))
    buf.seek(0)
    state = torch.load(buf)
    actor2.load_state_dict(state["actor"])
    critic2.load_state_dict(state["critic"])
    assert torch.allclose(actor2(obs), actor(obs)) and torch.allclose(critic2(obs), critic(obs))
    if isinstance(actor, DetachModel):
        assert actor2.aux_losses(obs)["R1"].item() == 0.0 and bool(actor2.trunk.env_anchor.valid)


@pytest.mark.parametrize("kind", ["detach", "tokenhsi", "cml"])
def test_shared_trunk_critic_reads_the_actors_trunk(kind: str) -> None:
    torch.manual_seed(0)
    cfg = dataclasses.replace(KINDS[kind], shared_trunk=True)
    obs = random_obs(8)
    actor, critic = build_actor_critic(cfg, SPEC, obs)
    assert not critic.owns_trunk and critic.head_groups == ("critic",)
    trunk_ids = {id(p) for p in actor.trunk.parameters()}
    assert not trunk_ids & {id(p) for p in critic.parameters()}, "trunk parameters listed twice"
    assert not any(k.startswith("trunk.") for k in critic.state_dict())
    # The value of a fresh trunk pass equals the value that reuses the actor's pass on the same obs.
    fresh = critic(obs)
    actor(obs)
    reused = critic(obs)
    assert torch.allclose(fresh, reused, atol=1e-6)
    # The value loss trains the shared trunk; the privileged group reaches the value.
    critic(obs).pow(2).mean().backward()
    aux_heads = {id(p) for m in getattr(actor.trunk, "pretrain_head_modules", list)()
                 for p in m.parameters()}  # DETACH's decoders: trained by aux losses only
    missing = [n for n, p in actor.trunk.named_parameters() if id(p) not in aux_heads and p.grad is None]
    assert not missing, f"value loss does not reach {missing}"
    moved = obs.clone()
    moved["critic"] = moved["critic"] + 1.0
    assert not torch.allclose(critic(moved), critic(obs))
    # A critic built without shared_trunk keeps its own trunk and refuses to be linked.
    _, own = build_actor_critic(KINDS[kind], SPEC, obs)
    assert own.owns_trunk
    with pytest.raises(ValueError, match="not built as a shared-trunk critic"):
        own.share_trunk_of(actor)


def test_snapshot_and_encoder_preservation() -> None:
    actor, critic, obs = build("detach")
    assert actor.aux_losses(obs)["R1"].item() == 0.0  # no snapshot yet
    actor.snapshot_encoders()
    with torch.no_grad():
        p = next(actor.trunk.env_encoder.parameters())
        p.add_(0.1)
    aux = actor.aux_losses(obs)
    assert aux["R1"].item() == pytest.approx(0.01 * p.numel(), rel=1e-3)
    assert aux["R2"].item() == 0.0
    critic.load_encoders_from(actor)
    for a, b in zip(actor.encoder_parameters(), critic.encoder_parameters()):
        assert torch.equal(a, b)


def test_aux_losses_keys_and_stage_combination() -> None:
    actor, _, obs = build("detach")
    aux = actor.aux_losses(obs)
    assert set(aux) == {
        "L_env", "L_self", "R_decouple", "MI", "R_temporal", "R_semantic_env", "R_semantic_self",
        "R_semantic", "L_fusion_quality", "R1", "R2", "R3",
    }
    assert all(v.dim() == 0 and torch.isfinite(v) for v in aux.values())
    for stage in L.STAGES:
        assert actor.aux_loss(obs, stage).dim() == 0
    with pytest.raises(ValueError, match="stage"):
        actor.aux_loss(obs, "warmup")
    abl, _, _ = build("ablation_a1")
    assert set(abl.aux_losses(obs)) == set(aux) and abl.aux_losses(obs)["L_env"].item() == 0.0


def test_aux_losses_reuse_the_forward_pass_on_the_same_obs() -> None:
    actor, _, obs = build("detach")
    fresh = actor.aux_losses(obs)
    actor(obs)  # training-mode forward with grad: cached for this obs object
    assert actor._forward_cache is not None
    reused = actor.aux_losses(obs, reuse_forward=True)
    assert actor._forward_cache is None  # one-shot
    for k in fresh:
        assert torch.allclose(fresh[k], reused[k], rtol=1e-5, atol=1e-6), k
    with torch.no_grad():
        actor(obs)
    assert actor._forward_cache is None  # rollouts (no grad) do not cache
    actor(obs).sum().backward()  # a graph already used: the default recomputes, so this works
    sum(actor.aux_losses(obs).values()).backward()


def test_multi_head_critic_returns_weighted_sum() -> None:
    _, critic, obs = build("cml")
    heads = critic.value_heads(obs)
    assert torch.allclose(critic(obs), heads.sum(-1, keepdim=True))
    critic.set_objective_weights([0.5, 0.25, 0.25])
    assert torch.allclose(critic(obs), heads @ torch.tensor([[0.5], [0.25], [0.25]]), atol=1e-6)
    with pytest.raises(ValueError):
        critic.set_objective_weights([1.0])


@pytest.mark.parametrize("name", ["detach", "tokenhsi", "cml", "mlp"])
def test_models_learn_a_toy_regression(name: str) -> None:
    """200 Adam steps of supervised regression of the action mean on a target that needs both
    the self and the env history."""
    spec = SMALL_SPEC
    torch.manual_seed(0)
    obs = random_obs(64, spec, seed=3)
    actor, _ = build_actor_critic(KINDS[name], spec, obs)
    actor.update_normalization(obs)
    g = torch.Generator().manual_seed(4)
    w_self = torch.randn(spec.self_steps * spec.self_dim, spec.num_actions, generator=g) / 8
    w_env = torch.randn(spec.env_steps * spec.env_dim, spec.num_actions, generator=g) / 10
    target = torch.tanh(obs["self"] @ w_self) + torch.tanh(obs["env"] @ w_env)
    opt = torch.optim.Adam(actor.parameters(), lr=1e-3)
    losses = []
    for _ in range(200):
        loss = (actor(obs) - target).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    print(f"{name}: regression loss {losses[0]:.3f} -> {losses[-1]:.3f}")
    assert losses[-1] < 0.3 * losses[0]


def test_pretraining_losses_decrease() -> None:
    torch.manual_seed(0)
    obs = random_obs(64, seed=5)
    actor, _ = build_actor_critic(KINDS["detach"], SPEC, obs)
    actor.update_normalization(obs)
    opt = torch.optim.Adam(actor.pretrain_parameters(), lr=3e-3)
    first = {k: v.item() for k, v in actor.aux_losses(obs).items()}
    for _ in range(60):
        loss = actor.aux_loss(obs, "pretrain")
        opt.zero_grad()
        loss.backward()
        opt.step()
    last = {k: v.item() for k, v in actor.aux_losses(obs).items()}
    assert last["L_env"] < 0.7 * first["L_env"]
    assert last["R_semantic_self"] < 0.7 * first["R_semantic_self"]


def test_unequal_history_lengths() -> None:
    spec = dataclasses.replace(SPEC, env_steps=3, critic_dim=16)
    for name in ("detach", "tokenhsi", "cml"):
        actor, critic, obs = build(name, spec=spec)
        assert actor(obs).shape == (8, spec.num_actions) and critic(obs).shape == (8, 1)
        if isinstance(actor, DetachModel):
            assert all(torch.isfinite(v) for v in actor.aux_losses(obs).values())


def test_mlp_history_frames_reads_only_the_newest_frames() -> None:
    cfg = dataclasses.replace(KINDS["mlp"], history_frames=1, obs_normalization=False)
    obs = random_obs(4)
    actor, _ = build_actor_critic(cfg, SPEC, obs)
    first = next(m for m in actor.mlp.modules() if isinstance(m, torch.nn.Linear))
    assert first.in_features == SPEC.self_dim + SPEC.env_dim + SPEC.num_skills
    older = obs.clone()  # change every frame but the newest: the action must not move
    older["self"][:, : -SPEC.self_dim] += 5.0
    older["env"][:, : -SPEC.env_dim] += 5.0
    assert torch.equal(actor(obs), actor(older))
    newest = obs.clone()
    newest["self"][:, -SPEC.self_dim:] += 5.0
    assert not torch.equal(actor(obs), actor(newest))
    flat = torch.cat([obs[g] for g in DEFAULT_OBS_GROUPS["actor"]], dim=-1)
    torch.testing.assert_close(actor.as_jit()(flat), actor(obs))  # exported with the same layout


def test_wrong_group_width_is_a_one_line_error() -> None:
    obs = random_obs(4)
    obs["env"] = torch.randn(4, 10)
    with pytest.raises(ValueError, match="'env' has width 10"):
        build_actor_critic(KINDS["detach"], SPEC, obs)


@pytest.mark.parametrize("name", list(KINDS))
def test_cfg_entries_carry_the_typed_config_and_resolve(name: str) -> None:
    actor_cfg, critic_cfg = rsl_rl_model_cfgs(KINDS[name], SPEC, default_std=0.3)
    yaml.safe_dump(to_plain({"actor": actor_cfg, "critic": critic_cfg}))  # dumpable for params files
    cls, kwargs = resolve_class(actor_cfg)
    assert kwargs["model"] == KINDS[name] and type(kwargs["model"]) is type(KINDS[name])
    assert kwargs["obs_spec"] == SPEC and kwargs["distribution_cfg"]["init_std"] == 0.3
    objectives = list(KINDS[name].critic_objectives)
    assert critic_cfg.get("value_objectives", ["task"]) == objectives


def test_a_model_config_of_the_wrong_kind_is_refused() -> None:
    obs = random_obs(4)
    actor_cfg, _ = rsl_rl_model_cfgs(KINDS["detach"], SPEC, default_std=1.0)
    cls, kwargs = resolve_class(actor_cfg)
    kwargs["model"] = KINDS["mlp"]
    with pytest.raises(TypeError, match="DetachModel needs a DetachCfg, got MLPCfg"):
        cls(obs, DEFAULT_OBS_GROUPS, "actor", SPEC.num_actions, **kwargs)


class FakeEnv:
    """Just enough of rsl_rl.env.VecEnv for one PPO iteration on random observations."""

    def __init__(self, num_envs: int = 8) -> None:
        self.num_envs, self.num_actions, self.max_episode_length = num_envs, SPEC.num_actions, 10
        self.episode_length_buf = torch.zeros(num_envs, dtype=torch.long)
        self.device, self.cfg = "cpu", {}
        self._seed = 0

    def get_observations(self) -> TensorDict:
        self._seed += 1
        return random_obs(self.num_envs, seed=self._seed)

    def step(self, actions: torch.Tensor):
        assert actions.shape == (self.num_envs, self.num_actions)
        rewards = -actions.pow(2).mean(-1)
        dones = torch.zeros(self.num_envs, dtype=torch.bool)
        dones[0] = True
        return self.get_observations(), rewards, dones, {"time_outs": dones.clone()}


@pytest.mark.parametrize("name", list(KINDS))
def test_rsl_rl_runner_trains_one_iteration(name: str) -> None:
    """The stock OnPolicyRunner + PPO build our classes from the cfg dicts and run act/update."""
    actor_cfg, critic_cfg = rsl_rl_model_cfgs(KINDS[name], SPEC, default_std=1.0)
    train_cfg = {
        "num_steps_per_env": 4,
        "save_interval": 100,
        "obs_groups": {k: list(v) for k, v in DEFAULT_OBS_GROUPS.items()},
        "algorithm": {"class_name": "PPO", "num_learning_epochs": 1, "num_mini_batches": 2, "learning_rate": 1e-4},
        "actor": actor_cfg,
        "critic": critic_cfg,
        "logger": "tensorboard",
        "run_name": "test",
    }
    torch.manual_seed(0)
    runner = OnPolicyRunner(FakeEnv(), train_cfg, log_dir=None, device="cpu")
    assert isinstance(runner.alg, PPO)
    before = [p.detach().clone() for p in runner.alg.actor.parameters()]
    runner.learn(1)
    after = list(runner.alg.actor.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(before, after))


@pytest.mark.parametrize("name", list(KINDS))
def test_zeroed_input_weights_make_a_model_ignore_unseen_inputs_and_still_learn_them(name: str) -> None:
    """`train.init_normalizers: merge` zeroes the weights that read inputs the source run never
    saw vary; each model's `input_weights()` must name exactly the layers that read them."""
    from detach.train.setup import zero_unseen_input_weights

    actor, critic, obs = build(name)
    for model in (actor, critic):
        lay = model.layout
        unseen = torch.zeros(sum(lay.dims), dtype=torch.bool)
        some = torch.zeros(sum(lay.dims), dtype=torch.bool)  # unseen in one frame only: kept
        for g in lay.groups:
            cols = lay.columns(g)
            if g == "env":
                unseen[cols[:5].reshape(-1)] = True
                some[cols[5:7, -1]] = True
            elif g in ("critic",) or (g == "task" and name != "tokenhsi"):  # TokenHSI masks by the one-hot
                half = cols.shape[0] // 2
                unseen[cols[:half].reshape(-1)] = True
                if g == "critic":  # TokenHSI's critic reads nothing else
                    some[cols[half:half + 2].reshape(-1)] = True
        assert zero_unseen_input_weights(model, unseen) > 0

        def changed(mask: torch.Tensor) -> TensorDict:
            out = obs.clone()
            for g, part in zip(lay.groups, torch.split(mask, list(lay.dims))):
                out[g] = out[g] + 3.0 * part.float()
            return out

        with torch.no_grad():
            torch.testing.assert_close(model(changed(unseen)), model(obs))
            assert not torch.allclose(model(changed(some)), model(obs))
        weights = [w for w, _cols in model.input_weights() if isinstance(w, torch.nn.Parameter)]
        assert weights and all(w.requires_grad for w in weights)
        model(changed(unseen)).pow(2).sum().backward()
        assert any(float(w.grad.abs().sum()) > 0 for w in weights if w.grad is not None)


def test_zeroing_unseen_input_weights_leaves_detachs_preserved_encoders_where_they_were() -> None:
    """R1/R2 pull the encoders toward θ* (their weights at the end of pre-training). Zeroing
    the columns of unseen inputs in the weights but not in θ* made R1 about 20 from the first
    Carry iteration, and its pull slowly restored the random weights on Follow's unseen inputs."""
    from detach.train.setup import zero_unseen_input_weights

    actor, _critic, obs = build("detach")
    actor.snapshot_encoders()
    before = {k: float(v.detach()) for k, v in actor.aux_losses(obs).items() if k in ("R1", "R2")}
    assert before == {"R1": 0.0, "R2": 0.0}
    unseen = torch.zeros(sum(actor.layout.dims), dtype=torch.bool)
    for g in ("env", "self"):
        unseen[actor.layout.columns(g)[:3].reshape(-1)] = True
    assert zero_unseen_input_weights(actor, unseen) > 0
    after = actor.aux_losses(obs)
    assert float(after["R1"].detach()) == 0.0 and float(after["R2"].detach()) == 0.0
