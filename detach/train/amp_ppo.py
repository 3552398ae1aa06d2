"""rsl-rl-lib's PPO extended with an adversarial motion prior, multi-objective critics and
stage-dependent auxiliary losses; selected through `algorithm.class_name`, rsl-rl unforked.

What it adds to PPO:
- AMP (`AmpCfg`): every env step, the discriminator scores the newest AMP window (`amp`
  group) conditioned on the skill one-hot (`task` group); the style reward is mixed with the
  task reward (`task_reward_weight`, `style_reward_weight`). After PPO's update the
  discriminator trains `disc_updates` times on reference windows from
  `reference_sampler(n) -> (amp, skill one-hot)` against this rollout's and replayed policy
  windows.
- Body-part discriminators (CML): one discriminator per entry of `amp_parts` (feature
  indices of the AMP window), each its own reward objective.
- Multi-objective critics (CML): a critic with `num_objectives = K` predicts one value per
  objective ([task, style or style parts]); GAE runs per objective and, with
  `per_objective_advantage_norm` (CML's), advantages are normalised per objective before their
  weighted sum; otherwise the weighted sum is normalised.
- Shared trunk (`model.shared_trunk`): the critic is linked to the actor's trunk before PPO
  builds its optimiser (`link_shared_trunk`), so the trunk's parameters are listed once.
- Stages (DETACH): `stage` is set by the runner each iteration. In "pretrain" PPO does not
  update; only `aux_loss_fn(obs, stage)` is minimised (encoder pre-training). In other stages
  PPO updates and then `aux_loss_fn` runs over the same rollout (alternating optimisation
  with the PPO optimiser, whose parameter list skips frozen parameters' missing gradients).
- Losses on the student's mean action (`policy_loss_fn`: the teachers' loss of
  `train.teachers`, `detach.train.teachers`, and the penalty of `train.action_bound_coef`,
  `detach.train.action_bounds`): after PPO's update they are minimised with PPO's optimiser for
  as many epochs and mini-batches as PPO's own update (not in DETACH's "pretrain" stage); with
  `teacher_only` PPO does not update at all (policy distillation on the student's own
  rollouts, DAgger-style).

Multi-GPU (rsl-rl's distributed path, `torchrun`): besides PPO's actor and critic, the
discriminators start from rank 0's weights and normaliser statistics (`broadcast_parameters`),
their gradients and those of the auxiliary losses are averaged over ranks before each
optimiser step, and the discriminators' normalisers are updated with every rank's windows, so
that all ranks hold the same networks after every update.
"""

from __future__ import annotations

from itertools import chain
from typing import Callable

import torch
from tensordict import TensorDict
from rsl_rl.algorithms import PPO
from rsl_rl.utils.utils import reduce_gradients_in_buckets

from detach.config.schema import AmpCfg
from detach.config.validate import Builder
from detach.models.structured import link_shared_trunk
from detach.train.discriminator import AmpDiscriminator, ReplayBuffer

REPLAY_KEY = "amp_replay_state"
"""Key of the AMP replay buffer's state in `AmpPPO.save()`'s dict."""
AuxLossFn = Callable[[TensorDict, str], tuple[torch.Tensor, dict[str, float]]]
PolicyLossFn = Callable[[TensorDict], tuple[torch.Tensor, dict[str, float]]]
ReferenceSampler = Callable[[int], tuple[torch.Tensor, torch.Tensor]]


class AmpPPO(PPO):
    def __init__(self, actor, critic, storage, amp: AmpCfg | None = None, task_specific: bool = True,
                 amp_parts: dict[str, list[int]] | None = None, per_objective_advantage_norm: bool = True,
                 **ppo_kwargs) -> None:
        """amp: the AMP settings (None = no AMP); task_specific: condition the discriminator on
        the skill one-hot; amp_parts: feature indices of the AMP window per body part (CML's
        body-part discriminators; None = one whole-body discriminator)."""
        if isinstance(amp, dict):  # a YAML train config (params/agent.yaml) read by stock rsl-rl code
            amp = Builder({}, "train_cfg (algorithm.amp)").build(AmpCfg, amp, ())
        link_shared_trunk(actor, critic)  # before PPO lists the parameters for its optimiser
        super().__init__(actor, critic, storage, **ppo_kwargs)
        if ppo_kwargs.get("optimizer", "adam") == "adam":
            # Fused Adam: the same update, ~4x faster per step on CPU for our ~10M parameters
            # (rsl-rl's resolve_optimizer takes only a name, so PPO built the plain one).
            self.optimizer = torch.optim.Adam(
                chain(self.actor.parameters(), self.critic.parameters()),
                lr=self.learning_rate, fused=True)
        self.amp = amp or AmpCfg(enabled=False)
        self.amp_enabled = self.amp.enabled
        self.task_weight = self.amp.task_reward_weight if self.amp_enabled else 1.0
        self.style_weight = self.amp.style_reward_weight if self.amp_enabled else 0.0
        self.conditional = task_specific
        self.per_objective_norm = per_objective_advantage_norm
        self.reference_sampler: ReferenceSampler | None = None
        self.aux_loss_fn: AuxLossFn | None = None
        self.policy_loss_fn: PolicyLossFn | None = None
        """Losses on the student's mean action (teachers, action bound), minimised after PPO's update."""
        self.teacher_only = False
        """Distillation: the teachers' loss alone trains the policy (PPO collects, no PPO update)."""
        self.critic_warmup_iterations = 0
        """The run's first iterations train the critic alone (`train.critic_warmup_iterations`)."""
        self.critic_warmup_left = 0
        """Of those, the updates still to come (set when training starts or resumes)."""
        self.critic_warmup_lr = 1.0e-3
        """Their learning rate (`train.critic_warmup_learning_rate`)."""
        self.reuse_frozen_features = True
        """Run the actor's frozen layers once per update (`train.reuse_frozen_features`)."""
        self.stage = "ppo"
        heads = tuple(getattr(critic, "value_objectives", ()) or ())
        self.num_objectives = len(heads) if heads else int(getattr(critic, "num_objectives", 1))
        if len(heads) > 1:
            critic.sum_value_heads = False  # per-head values through PPO's value path
        obs = storage.observations
        amp_dim = obs["amp"].shape[-1] if self.amp_enabled else 0
        cond_dim = obs["task"].shape[-1] if (self.amp_enabled and self.conditional) else 0
        self.amp_parts = {name: torch.as_tensor(idx, dtype=torch.long, device=self.device)
                          for name, idx in (amp_parts or {}).items()} or {"all": None}
        self.discriminators = torch.nn.ModuleDict()
        if self.amp_enabled:
            for name, idx in self.amp_parts.items():
                width = amp_dim if idx is None else int(idx.numel())
                self.discriminators[name] = AmpDiscriminator(
                    width, cond_dim, self.amp.disc_hidden, self.amp.objective).to(self.device)
            self.disc_optimizer = torch.optim.Adam(
                self.discriminators.parameters(), lr=self.amp.learning_rate,
                weight_decay=self.amp.weight_decay, fused=True)
            self.replay = ReplayBuffer(self.amp.replay_size, amp_dim, cond_dim, self.device)
        expected = 1 + (len(self.amp_parts) if self.amp_enabled else 0)
        if self.num_objectives not in (1, expected):
            raise ValueError(f"critic predicts {self.num_objectives} objectives; this AMP setup "
                             f"has {expected} (task + {len(self.amp_parts)} style)")
        k, t, n = self.num_objectives, storage.num_transitions_per_env, storage.num_envs
        self.objective_weights = self._objective_weights().to(self.device)
        if k > 1:
            storage.values = torch.zeros(t, n, k, device=self.device)
            storage.returns = torch.zeros(t, n, k, device=self.device)
        self.objective_rewards = torch.zeros(t, n, k, device=self.device)
        self._rollout_amp: list[torch.Tensor] = []
        self._rollout_cond: list[torch.Tensor] = []
        self._reward_sums = {"task": 0.0, "style": 0.0, "count": 0}

    def _objective_weights(self) -> torch.Tensor:
        parts = len(self.amp_parts) if self.amp_enabled else 0
        if self.num_objectives == 1:
            return torch.ones(1)
        return torch.tensor([self.task_weight] + [self.style_weight / parts] * parts)

    # ------------------------------------------------------------------ rollout
    def _style_rewards(self, amp_obs: torch.Tensor, cond: torch.Tensor | None) -> torch.Tensor:
        """[N, parts] style reward of each discriminator."""
        out = []
        for name, disc in self.discriminators.items():
            idx = self.amp_parts[name]
            x = amp_obs if idx is None else amp_obs.index_select(-1, idx)
            out.append(disc.style_reward(x, cond))
        return torch.stack(out, dim=-1)

    def process_env_step(self, obs: TensorDict, rewards: torch.Tensor, dones: torch.Tensor,
                         extras: dict) -> None:
        task_reward = rewards.reshape(-1).to(self.device)
        objectives = [task_reward]
        if self.amp_enabled:
            amp_obs = obs["amp"]
            cond = self.transition.observations["task"] if self.conditional else None
            style = self._style_rewards(amp_obs, cond)
            self._rollout_amp.append(amp_obs.clone())
            if cond is not None:
                self._rollout_cond.append(cond.clone())
            objectives += list(style.unbind(-1))
            self._reward_sums["style"] += float(style.mean())
        self._reward_sums["task"] += float(task_reward.mean())
        self._reward_sums["count"] += 1
        per_objective = torch.stack(objectives, dim=-1)  # [N, 1 + parts]
        if self.num_objectives == 1:
            mixed = self.task_weight * task_reward
            if self.amp_enabled:
                mixed = mixed + self.style_weight * per_objective[:, 1:].mean(-1)
            per_objective = mixed.unsqueeze(-1)
        values = self.transition.values
        time_outs = extras.get("time_outs")
        if time_outs is not None:  # bootstrap at time limits, per objective
            per_objective = per_objective + self.gamma * values * time_outs.reshape(-1, 1).to(
                self.device).float()
        self.objective_rewards[self.storage.step].copy_(per_objective)
        self.transition.rewards = (per_objective * self.objective_weights).sum(-1)
        self.transition.dones = dones
        self.storage.add_transition(self.transition)
        self.transition.clear()
        self.actor.reset(dones)
        self.critic.reset(dones)

    def compute_returns(self, obs: TensorDict) -> None:
        """GAE per objective; advantages normalised per objective, then weighted and summed."""
        st = self.storage
        hidden = self.critic.get_hidden_state()
        last_values = self.critic(obs).detach().reshape(st.num_envs, -1)
        self.critic.reset(hidden_state=hidden)
        advantage = torch.zeros_like(last_values)
        values = st.values
        for step in reversed(range(st.num_transitions_per_env)):
            next_values = last_values if step == st.num_transitions_per_env - 1 else values[step + 1]
            not_done = 1.0 - st.dones[step].float()
            delta = self.objective_rewards[step] + not_done * self.gamma * next_values - values[step]
            advantage = delta + not_done * self.gamma * self.lam * advantage
            st.returns[step] = advantage + values[step]
        adv = st.returns - values
        if not self.per_objective_norm:
            adv = (adv * self.objective_weights).sum(-1, keepdim=True)
        if not self.normalize_advantage_per_mini_batch:
            flat = adv.reshape(-1, adv.shape[-1])
            adv = (adv - flat.mean(0)) / (flat.std(0) + 1e-8)
        st.advantages = (adv * self.objective_weights).sum(-1, keepdim=True) if self.per_objective_norm else adv

    # ------------------------------------------------------------------ learning
    def update(self) -> dict[str, float]:
        try:
            return self._update()
        finally:
            key = self._frozen_features_key()
            if key is not None and key in self.storage.observations.keys():
                del self.storage.observations[key]  # the next rollout's steps carry no such key

    def _frozen_features_key(self) -> str | None:
        """The actor's key for its frozen features; None for an actor without the hook (stock
        rsl-rl models)."""
        fn = getattr(self.actor, "frozen_features_key", None)
        return fn() if fn is not None else None

    def _attach_frozen_features(self) -> None:
        """Run the actor's frozen layers once over the rollout (DETACH's encoders in stage 2) and
        attach their outputs to the stored observations for this update, so that the passes
        over mini-batches read them instead of running those layers again in every mini-batch
        (`train.reuse_frozen_features`). Called before PPO's epochs and again before the
        auxiliary and teachers' passes, since PPO's update ends by moving the input normalisers."""
        key = self._frozen_features_key()
        if not self.reuse_frozen_features or key is None:
            return
        obs = self.storage.observations
        if key in obs.keys():
            del obs[key]  # computed before the normalisers moved
        feats = self.actor.frozen_features(obs.flatten(0, 1))
        if feats is not None:
            obs[key] = feats.reshape(obs.batch_size)

    def _update(self) -> dict[str, float]:
        warmup = False
        if self.stage == "pretrain" or self.teacher_only:
            self.storage.clear()
            losses: dict[str, float] = {}
        else:
            self._attach_frozen_features()
            if self.critic_warmup_left > 0:
                warmup = True
                self.critic_warmup_left -= 1
                losses = self._update_critic_alone()
            else:
                losses = super().update()
        if self.amp_enabled:
            losses.update(self._update_discriminators())
        aux = self.aux_loss_fn is not None and not warmup
        teach = self.policy_loss_fn is not None and self.stage != "pretrain" and not warmup
        if aux or teach:
            self._attach_frozen_features()
        obs = self.storage.observations.flatten(0, 1)
        if aux:
            losses.update(self._update_aux(obs))
        if teach:
            losses.update(self._minimise(self.policy_loss_fn, obs, self.num_learning_epochs))
        count = max(self._reward_sums["count"], 1)
        losses["reward_task"] = self._reward_sums["task"] / count
        if self.amp_enabled:
            losses["reward_style"] = self._reward_sums["style"] / count
        self._reward_sums = {"task": 0.0, "style": 0.0, "count": 0}
        return losses

    def _update_critic_alone(self) -> dict[str, float]:
        """PPO's update with every parameter of the policy frozen (a trunk it shares with the
        critic included) at the warm-up learning rate and without the value clip: only the
        critic's own layers learn, as far as the new returns ask. The adaptive schedule sees a KL
        of 0 and keeps the rate; the stage's rate and clip are restored after."""
        frozen = [p for p in self.actor.parameters() if p.requires_grad]
        rate, clipped = self.learning_rate, self.use_clipped_value_loss
        for p in frozen:
            p.requires_grad_(False)
        self._set_learning_rate(self.critic_warmup_lr)
        self.use_clipped_value_loss = False  # the clip holds each update within 0.2 of the rollout's values
        try:
            losses = super().update()
        finally:
            for p in frozen:
                p.requires_grad_(True)
            self._set_learning_rate(rate)
            self.use_clipped_value_loss = clipped
        losses["critic_warmup"] = 1.0
        return losses

    def _set_learning_rate(self, rate: float) -> None:
        self.learning_rate = rate
        for group in self.optimizer.param_groups:
            group["lr"] = rate

    def _update_discriminators(self) -> dict[str, float]:
        if not self._rollout_amp:
            return {}
        if self.reference_sampler is None:
            raise RuntimeError("AMP is enabled but no reference_sampler was set")
        policy = torch.cat(self._rollout_amp)
        cond = torch.cat(self._rollout_cond) if self._rollout_cond else None
        self._rollout_amp.clear()
        self._rollout_cond.clear()
        sums: dict[str, float] = {}
        for _ in range(self.amp.disc_updates):
            n = min(self.amp.batch_size, policy.shape[0])
            idx = torch.randint(0, policy.shape[0], (n,), device=self.device)
            pol_obs, pol_cond = policy[idx], (cond[idx] if cond is not None else None)
            if self.replay.size > 0:
                old_obs, old_cond = self.replay.sample(n)
                pol_obs = torch.cat([pol_obs, old_obs])
                pol_cond = torch.cat([pol_cond, old_cond]) if pol_cond is not None else None
            ref_obs, ref_cond = self.reference_sampler(pol_obs.shape[0])
            ref_obs, ref_cond = ref_obs.to(self.device), ref_cond.to(self.device)
            if pol_cond is None:
                ref_cond = None
            total = torch.zeros((), device=self.device)
            for name, disc in self.discriminators.items():
                sel = self.amp_parts[name]
                pick = (lambda x: x) if sel is None else (lambda x, s=sel: x.index_select(-1, s))
                terms = disc.loss(pick(ref_obs), pick(pol_obs), ref_cond, pol_cond,
                                  self.amp.grad_penalty, self.amp.logit_reg)
                total = total + terms["total"]
                for key, value in terms.items():
                    tag = f"amp/{key}" if len(self.discriminators) == 1 else f"amp_{name}/{key}"
                    sums[tag] = sums.get(tag, 0.0) + float(value.detach()) / self.amp.disc_updates
            self.disc_optimizer.zero_grad()
            total.backward()
            self._average_gradients(self.discriminators.parameters())
            self.disc_optimizer.step()
        with torch.no_grad():
            seen = self._gather(policy)
            for name, disc in self.discriminators.items():
                sel = self.amp_parts[name]
                disc.normalizer.update(seen if sel is None else seen.index_select(-1, sel))
        self.replay.insert(policy, cond)
        return sums

    def _update_aux(self, obs: TensorDict) -> dict[str, float]:
        return self._minimise(lambda batch: self.aux_loss_fn(batch, self.stage), obs, 1)

    def _minimise(self, loss_fn: PolicyLossFn, obs: TensorDict, epochs: int) -> dict[str, float]:
        """`epochs` passes of PPO's mini-batches over the rollout's observations, one step of
        PPO's optimiser on `loss_fn` each; returns the mean of each logged value. The teachers'
        loss (`train.teachers`) takes as many steps as PPO's update, so that neither
        objective's steps outnumber the other's."""
        sums: dict[str, float] = {}
        batch = max(obs.batch_size[0] // self.num_mini_batches, 1)
        params = [p for g in self.optimizer.param_groups for p in g["params"]]
        steps = 0
        for _ in range(epochs):
            perm = torch.randperm(obs.batch_size[0], device=self.device)
            for start in range(0, perm.numel() - batch + 1, batch):
                loss, logs = loss_fn(obs[perm[start:start + batch]])
                if loss.requires_grad:
                    self.optimizer.zero_grad()
                    loss.backward()
                    self._average_gradients(params)
                    torch.nn.utils.clip_grad_norm_(params, self.max_grad_norm)
                    self.optimizer.step()
                for key, value in logs.items():
                    sums[key] = sums.get(key, 0.0) + float(value)
                steps += 1
        return {k: v / max(steps, 1) for k, v in sums.items()}

    # ------------------------------------------------------------------ multi-GPU
    def broadcast_parameters(self) -> None:
        """Rank 0's actor, critic, discriminators and their normalisers on every rank."""
        super().broadcast_parameters()
        for tensor in self.discriminators.state_dict().values():
            torch.distributed.broadcast(tensor, src=0)

    def _average_gradients(self, params) -> None:
        """Average the gradients of params over ranks (no-op on one process)."""
        if self.is_multi_gpu:
            reduce_gradients_in_buckets(params, self.gpu_world_size, self.grad_reduce_bucket_mb)

    def _gather(self, x: torch.Tensor) -> torch.Tensor:
        """x of every rank, concatenated in rank order (x itself on one process)."""
        if not self.is_multi_gpu:
            return x
        parts = [torch.empty_like(x) for _ in range(self.gpu_world_size)]
        torch.distributed.all_gather(parts, x.contiguous())
        return torch.cat(parts)

    # ------------------------------------------------------------------ state
    def save(self) -> dict:
        """PPO's state plus the discriminators, their optimiser and (under `REPLAY_KEY`) the
        AMP replay buffer, which the runner stores beside the checkpoint (it is large)."""
        saved = super().save()
        if self.amp_enabled:
            saved["discriminator_state_dict"] = self.discriminators.state_dict()
            saved["disc_optimizer_state_dict"] = self.disc_optimizer.state_dict()
            saved[REPLAY_KEY] = self.replay.state_dict()
        return saved

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        """Everything `save` wrote; a checkpoint without a replay buffer (an older one, or one
        whose sidecar retention removed) leaves the buffer empty."""
        load_iteration = super().load(loaded_dict, load_cfg, strict)
        if self.amp_enabled and "discriminator_state_dict" in loaded_dict:
            self.discriminators.load_state_dict(loaded_dict["discriminator_state_dict"],
                                                strict=strict)
            if load_cfg is None or load_cfg.get("optimizer"):
                self.disc_optimizer.load_state_dict(loaded_dict["disc_optimizer_state_dict"])
        if self.amp_enabled and loaded_dict.get(REPLAY_KEY) is not None:
            self.replay.load_state_dict(loaded_dict[REPLAY_KEY])
        return load_iteration

    def train_mode(self) -> None:
        super().train_mode()
        self.discriminators.train()

    def eval_mode(self) -> None:
        super().eval_mode()
        self.discriminators.eval()
