"""Typed, frozen sections of a run configuration.

Every YAML section maps onto one dataclass below; `detach.config` validates raw YAML into
these types, so the rest of the code never sees an unchecked dict. A field's doc is the string
under it; a numeric field whose type admits values a run cannot use declares its range there
too (`ranged`, `detach.config.ranges`). Units: metres, seconds, radians; positions are world
frame unless a field says otherwise.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import ClassVar, Literal

from detach.config.ranges import AT_LEAST_0, AT_LEAST_1, ENV_COUNT, FRACTION, POSITIVE, RANGE, Range, ranged
from detach.config.yaml_source import ConfigOrigin

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class SceneObjectCfg:
    """One object of a scene; its index in `scene` is its object id (`scene_K`)."""

    name: str
    category: str
    """Procedural category (see `detach-scene list`) or a 3D-FUTURE category."""
    model_id: str
    """Asset folder name: `<assets>/<category>/<model_id>/`."""
    pos3d: Vec3
    """World position of the object's bounding-box centre."""
    static: bool = True
    z_rot_angle: float = 0.0
    size: Vec3 | None = None
    """Bounding-box size (x, y, z) in metres after Z-up/+Y-facing normalisation; None keeps
    the generator's or the source mesh's own size."""
    variant: int = 0
    """Seed of the procedural generator (several variants per category)."""
    source: str = "procedural"
    """`procedural` or a mesh path / 3D-FUTURE model folder relative to `--source`."""
    mass: float = 5.0
    """Mass in kg of a dynamic object (ignored for static ones)."""


@dataclass(frozen=True)
class HumanoidCfg:
    init_pos2d: Vec2 = (0.0, 0.0)
    init_rot_randomize: bool = True
    init_yaw: float = 0.0
    """Yaw in radians when `init_rot_randomize` is false."""


@dataclass(frozen=True)
class TaskCfg:
    """The task proper: scene, plan and its targets (TokenHSI vocabulary)."""

    name: str
    scene: tuple[SceneObjectCfg, ...] = ()
    trajectories: dict[int, tuple[Vec2, ...]] = field(default_factory=dict)
    target_positions: tuple[Vec3, ...] = ()
    humanoid: HumanoidCfg = HumanoidCfg()
    plan: tuple[str, ...] = ("follow",)
    """Skill names (`detach.skills`: follow, carry, climb, sit, plug-ins; `traj` = follow)."""
    target_object: tuple[int | tuple[int, ...], ...] = (0,)
    """The object of each plan entry (scene index; for carry the box). A list of indices makes
    each episode pick one of them at random (e.g. one of nine boxes)."""
    sample_target_from: tuple[str, ...] = ("traj_0",)
    """`traj_K` (trajectory K; procedural when K is `rand`), `tarpos_K`, `scene_K`."""


@dataclass(frozen=True)
class SimCfg:
    backend: str = "mujoco_batch"
    """Physics backend (`detach.sim`): `mujoco_batch` (CPU, all cores) or `warp` (MuJoCo Warp,
    GPU; the `[warp]` extra)."""
    num_envs: int = ranged(64, ENV_COUNT)
    physics_dt: float = ranged(1.0 / 120.0, POSITIVE)
    substeps: int = ranged(4, AT_LEAST_1)
    """Physics steps per control step: 1/120 s x 4 = 30 Hz control."""
    nthread: int = ranged(0, AT_LEAST_0)
    """Threads stepping the batch; 0 = all cores."""
    friction: float = ranged(1.0, AT_LEAST_0)
    solver_iterations: int = ranged(4, AT_LEAST_1)
    sleep: bool | None = None
    """Let resting objects sleep (MuJoCo islands): untouched boxes and furniture cost nothing
    until something touches them (~35% less physics per step in the LH scenes). None: the
    backend's default (on with mujoco_batch, off with warp, which does not support it)."""
    nconmax: int = ranged(96, AT_LEAST_1)
    """warp: contacts allocated per world (the buffer is shared by all worlds)."""
    njmax: int = ranged(256, AT_LEAST_1)
    """warp: constraint rows allocated per world (contacts x 4 pyramid edges, joint limits,
    the grasp weld); a world past it raises an error naming this key."""
    cuda_graph: bool = True
    """warp on a CUDA device: replay each control step's launches as one CUDA graph (false:
    launch them one by one, slower; for debugging a capture)."""
    compile: bool = False
    """Run the env's own per-step tensor work (targets, rewards, transitions, observations) as
    a few `torch.compile` graphs instead of ~800 small eager ops (`LHEnv`). Same results;
    the first env of a process compiles for ~1-3 minutes (seconds from the cache torch keeps
    under /tmp). Needs a C++ compiler on a CPU, Triton on a GPU."""


@dataclass(frozen=True)
class HeightMapCfg:
    enabled: bool = True
    grid: int = ranged(25, AT_LEAST_1)
    spacing: float = ranged(0.1, POSITIVE)
    camera_height: float = 10.0


@dataclass(frozen=True)
class TrajectoryGenCfg:
    """Procedural reference trajectories for `follow` (paper: Data Generation Parameters)."""

    num_samples: int = ranged(10, AT_LEAST_1)
    """Points of the path ahead in each env observation frame, `sample_dt` s apart."""
    sample_dt: float = ranged(0.5, POSITIVE)
    speed_min: float = ranged(1.4, AT_LEAST_0)
    speed_max: float = ranged(1.5, AT_LEAST_0)
    accel_max: float = 2.0
    sharp_turn_prob: float = ranged(0.02, FRACTION)
    sharp_turn_angle: float = 1.57
    num_verts: int = ranged(101, Range(2))
    """Vertices of one generated trajectory (covers a whole episode)."""


@dataclass(frozen=True)
class EnvCfg:
    character: str = "humanoid"
    """A registered character (`detach.character`): humanoid or puppet."""
    skills: tuple[str, ...] = ()
    """The run's skills, in the order of the `task` one-hot and the AMP condition (their number
    is its width): every skill of the plan and any others the policy should know. Empty: follow,
    carry, climb, sit, then the plan's other skills in registry order; filled in when a run is
    created, so that config.yaml records it (a config.yaml without it means that list)."""
    episode_length: int = ranged(1200, AT_LEAST_1)
    success_threshold: float = ranged(0.3, POSITIVE)
    max_transition_steps: int = ranged(60, AT_LEAST_1)
    termination_height: float = ranged(0.15, AT_LEAST_0)
    fall_rule: Literal["pelvis", "body"] = "pelvis"
    """When an episode ends as a fall: `pelvis`, the pelvis below `termination_height`; `body`,
    any body but the feet below it (AMP's and TokenHSI's early termination: a knee, hand or
    head on the floor ends the episode, so a policy cannot learn to crawl or kneel)."""
    traj_fail_distance: float = ranged(4.0, POSITIVE)
    init: Literal["default", "random", "mixed"] = "mixed"
    mixed_init_prob: float = ranged(0.5, FRACTION)
    init_clips: Literal["first_skill", "prop_free", "all"] = "first_skill"
    """Which clips reference-state starts (`init: random | mixed`) are drawn from:
    `first_skill`, the clips of the first subtask's skill (`Skill.motion_labels`, e.g. Follow's
    walk, turn and idle) that need no prop; `prop_free`, every clip that needs no prop (every
    skill's walking, turning, standing and carrying poses); `all`, every clip, also a frame on
    top of a step or on a seat the env does not have there (the character then starts in the
    air or sitting on nothing: before 2026-12-07 every run started so)."""
    mid_task_init_prob: float = ranged(0.0, FRACTION)
    """Training only: the share of episodes that start from the middle of their first
    subtask's task where its skill offers such states (Carry: at the box with the hands on its
    lid, or the box carried part of the way; TokenHSI's initialisation from its box clips;
    Climb: standing beside the object, facing it). Needs a character that can start holding
    an object (the puppet)."""
    subtask_start_prob: float = ranged(0.0, FRACTION)
    """Training only: the share of episodes of a plan of two or more subtasks that start at a
    later subtask (uniform over those the scripted oracle reached), from the state the oracle
    was in when that subtask began (`detach.envs.subtask_starts`). Needs a scriptable
    character (the puppet)."""
    history_self: int = ranged(5, AT_LEAST_1)
    history_env: int = ranged(5, AT_LEAST_1)
    amp_obs_steps: int = ranged(10, AT_LEAST_1)
    iet: Literal["none", "last_subtask", "all"] = "last_subtask"
    task_specific_discrimination: bool = True
    height_map: HeightMapCfg = HeightMapCfg()
    trajectory: TrajectoryGenCfg = TrajectoryGenCfg()
    climb_pelvis_height: float = 0.9
    """Climb target = the object's climb point (top surface) raised by this much (m): a
    standing pelvis; `climb` succeeds with the pelvis at or above it (within the threshold)."""
    follow_on_path_frac: float = ranged(0.9, FRACTION)
    """A follow subtask succeeds when its end is reached and the pelvis was within
    `success_threshold` of the path (XY) for at least this fraction of its steps."""


@dataclass(frozen=True)
class RewardsCfg:
    power_coeff: float = 0.0005
    dyn_obj_speed_penalty_coeff: float = 1.0
    dyn_obj_speed_threshold: float = 1.5
    paid_skills: tuple[str, ...] | None = None
    """Only subtasks of these skills earn their task reward terms (None: every skill). The
    zero-shot reading of the paper's protocol trains LH1 with [follow, carry]: climb and sit
    are never rewarded, so their success measures skill generalisation."""
    terms: dict[str, float] = field(default_factory=dict)
    """Weights of named reward terms (`<skill>/<term>`); printed as a table at start-up."""
    subtask_bonus: float = ranged(0.0, AT_LEAST_0)
    """Reward paid once, at the control step a subtask's transition fires, for subtasks of the
    paid skills. Each skill's terms pay at most 1 per step, and most near its own end: the
    scripted oracle earns 1.0 per step holding Follow's end point and 0.15 in Carry's first
    ten steps. Without a bonus, a policy can earn more by lingering just outside a subtask's
    success distance than by moving on. Off by default: 20 lowered LH1's Follow success
    (docs/PROTOCOL.md)."""
    done_subtask_reward: float = ranged(0.0, AT_LEAST_0)
    """Reward paid at every step for each subtask of a paid skill the episode has completed
    (subtasks a late start skipped count as completed). At or above the most one subtask's
    terms pay per step (1 with the default weights) moving on never lowers the per-step
    reward, so lingering outside a subtask's success distance stops paying; unlike
    `subtask_bonus` it is paid for as long as the episode lasts, not once. Off by default
    (docs/PROTOCOL.md)."""


@dataclass(frozen=True)
class EvalCfg:
    trials: int = ranged(100, AT_LEAST_1)
    max_transition_steps: int = ranged(20, AT_LEAST_1)
    num_envs: int = ranged(16, ENV_COUNT)
    confidence: float = ranged(0.95, Range(0, 1, open_low=True, open_high=True))


BUILTIN_MODELS = "detach.models.configs"
"""The torch-free module of the built-in model kinds' config classes, which registers them
(`register_model_kind`) when imported: imported by name the first time a kind is looked up, so
the configuration layer depends on no network and imports no torch."""
MODEL_KIND_ENTRY_POINTS = "detach.model_kinds"
"""Entry-point group of installed add-on packages: each entry names a model kind's module (or
its config class); loading it registers the kind. A model YAML may instead give
`kind: package.module:ConfigClass` for a kind that is not installed."""

_KIND_CLASSES: dict[str, type["ModelCfg"]] = {}


def register_model_kind(kind: str, config_class: type["ModelCfg"] | None) -> None:
    """Map a model kind to its config class; called for the built-in kinds by `BUILTIN_MODELS`
    and for every kind by `register_model`. None removes the kind and the `package.module:Class`
    names that resolved to its class."""
    if config_class is not None:
        _KIND_CLASSES[kind] = config_class
        return
    removed = _KIND_CLASSES.pop(kind, None)
    for name in [k for k, cls in _KIND_CLASSES.items() if cls is removed and ":" in k]:
        del _KIND_CLASSES[name]


def kind_of(config_class: type["ModelCfg"]) -> str:
    """The kind a config class declares: the default of its `kind` field."""
    return next(f.default for f in dataclasses.fields(config_class) if f.name == "kind")


def registered_model_kinds() -> dict[str, type["ModelCfg"]]:
    """Every model kind by name: the built-ins, the installed add-ons and those registered in
    this process (an add-on whose entry point fails to load is left out)."""
    importlib.import_module(BUILTIN_MODELS)
    for ep in entry_points(group=MODEL_KIND_ENTRY_POINTS):
        if ep.name not in _KIND_CLASSES:
            try:
                ModelCfg.kind_class(ep.name)
            except (ValueError, ImportError):
                continue
    return {kind: cls for kind, cls in _KIND_CLASSES.items() if ":" not in kind}


@dataclass(frozen=True)
class ModelCfg:
    """What every network of the study reads; `kind` picks the config class of the network
    (a built-in kind's in `detach.models.configs`), which adds that network's own fields."""

    kind: str = "mlp"
    adapter_units: tuple[int, ...] = (1024, 512)
    """Hidden widths of the head MLP (policy or value head)."""
    activation: str = "elu"
    critic_objectives: tuple[str, ...] = ("task",)
    """Value heads of the critic: one per reward objective (CML's multi-head critic)."""
    init_noise_std: float | None = None
    """Initial action std of the Gaussian policy; None = the character's (`Character.action_std`),
    filled in when a run is created so that config.yaml records the number."""
    learn_noise_std: bool = True
    """Train the action std with PPO; false keeps it at `init_noise_std` (TokenHSI's fixed
    log-std of -2.9)."""
    obs_normalization: bool = True
    """Running mean/std normalisation of the concatenated observation groups (rsl-rl's
    EmpiricalNormalization) before the network; reconstruction targets are normalised too."""

    staged: ClassVar[bool] = False
    """Trained with DETACH's 3-stage protocol (`train.stages`)."""

    def builds_on(self) -> str | None:
        """The key that makes this model train on top of an earlier stage's weights (then
        `train.init_from` is required: a frozen random base would train silently), or None."""
        return None

    @classmethod
    def kind_class(cls, kind: str) -> type["ModelCfg"]:
        """The config class of a model kind: a registered kind (the built-ins first), an
        installed entry point of `MODEL_KIND_ENTRY_POINTS`, or `package.module:Class`;
        ValueError naming the kinds."""
        if kind not in _KIND_CLASSES:
            importlib.import_module(BUILTIN_MODELS)
        if kind in _KIND_CLASSES:
            return _KIND_CLASSES[kind]
        found = {ep.name: ep for ep in entry_points(group=MODEL_KIND_ENTRY_POINTS)}
        if kind in found:
            target = found[kind].load()
        elif ":" in kind:
            module, _, name = kind.partition(":")
            try:
                target = getattr(importlib.import_module(module), name)
            except (ImportError, AttributeError) as exc:
                raise ValueError(f"model kind '{kind}' cannot be imported ({exc})") from None
        else:
            available = ", ".join(sorted(k for k in _KIND_CLASSES if ":" not in k))
            raise ValueError(f"unknown model kind '{kind}'; available: {available}, or package.module:ConfigClass")
        if isinstance(target, type) and issubclass(target, ModelCfg):
            _KIND_CLASSES[kind] = target
        elif kind not in _KIND_CLASSES:  # an entry point naming a module registers its kind on import
            raise ValueError(f"model kind '{kind}' names {target!r}, not a ModelCfg subclass")
        return _KIND_CLASSES[kind]


@dataclass(frozen=True)
class AmpCfg:
    enabled: bool = True
    task_reward_weight: float = ranged(0.5, AT_LEAST_0)
    style_reward_weight: float = ranged(0.5, AT_LEAST_0)
    disc_hidden: tuple[int, ...] = (1024, 512)
    objective: Literal["lsgan", "logistic"] = "lsgan"
    grad_penalty: float = ranged(5.0, AT_LEAST_0)
    logit_reg: float = ranged(0.01, AT_LEAST_0)
    weight_decay: float = ranged(0.0001, AT_LEAST_0)
    replay_size: int = ranged(100000, AT_LEAST_1)
    batch_size: int = ranged(512, AT_LEAST_1)
    learning_rate: float = ranged(0.0001, POSITIVE)
    disc_updates: int = ranged(2, AT_LEAST_0)
    """Discriminator mini-batch updates after each PPO update."""
    body_parts: tuple[str, ...] = ()
    """Body-part discriminators (CML): e.g. (upper, lower); empty = one whole-body one."""
    skill_weights: dict[str, float] = field(default_factory=dict)
    """With task-specific discrimination: relative frequency of each skill among the reference
    windows (the skills of the run's plan only; an unlisted one gets the mean weight; empty =
    uniform)."""
    label_weights: dict[str, float] = field(default_factory=dict)
    """Relative weight of each motion label (idle, walk, turn, step_up, sit, carry) when clips
    are drawn, for the discriminator's reference windows and reference-state starts alike
    (within a skill's labels, renormalised): e.g. `{idle: 0}` leaves standing out of Follow's
    prior. A label left out weighs 1; empty = every label equally likely (a third of Follow's
    windows and starts are then idle)."""


@dataclass(frozen=True)
class StagesCfg:
    """DETACH's progressive protocol, in PPO iterations (0 disables a stage)."""

    pretrain: int = ranged(0, AT_LEAST_0)
    fusion: int = ranged(0, AT_LEAST_0)
    joint: int = ranged(0, AT_LEAST_0)


@dataclass(frozen=True)
class KeepCheckpointsCfg:
    """Which checkpoints a run keeps: each save deletes the others (a humanoid checkpoint is
    40-70 MB). The newest is always kept; resuming falls back to the previous one when the
    newest is unreadable, hence more than one by default."""

    last: int = ranged(3, AT_LEAST_0)
    """The newest `last` checkpoints (0 keeps every checkpoint)."""
    every: int = ranged(500, AT_LEAST_0)
    """Also each checkpoint whose iteration count (iteration + 1) is a multiple of `every`,
    for later evaluation of the learning curve (0: none)."""


@dataclass(frozen=True)
class CloneStartCfg:
    """A start cloned from the motion clips (`detach.train.clip_clone`), a training aid for the
    humanoid: before the first PPO iteration of a run from scratch the actor is fitted to the
    clips' own hinge targets, played open-loop from reference starts for `rounds` resets of
    `steps` control steps each, over `epochs` passes. From a random actor the humanoid's PPO
    settled on standing still; from the clone it steps. `rounds` 0 (the default) disables it."""

    rounds: int = ranged(0, AT_LEAST_0)
    steps: int = ranged(45, AT_LEAST_1)
    """Control steps per reset (1.5 s at 30 Hz: a clip is rarely longer before the humanoid falls)."""
    epochs: int = ranged(30, AT_LEAST_1)


@dataclass(frozen=True)
class BalanceAssistCfg:
    """A training aid for the humanoid (an assistive-force curriculum, as in Yu, Turk and Liu
    2018): a spring-damper torque on the pelvis that rights its tilt (roll and pitch, never
    yaw), at full strength for `hold_iterations`, fading linearly to zero over the next
    `fade_iterations`, off after. It lets a policy step forward without tipping over while it
    learns to walk, then hands balance back to it. Training envs only: evaluation, play and
    every validation choice run without it. `torque` 0 (the default) disables it."""

    torque: float = ranged(0.0, AT_LEAST_0)
    """N m per radian of pelvis tilt (the humanoid's gravity torque is ~530 N m/rad)."""
    damping: float = ranged(0.0, AT_LEAST_0)
    """N m s/rad on the pelvis's roll and pitch rates."""
    hold_iterations: int = ranged(0, AT_LEAST_0)
    """PPO iterations at full strength, from the run's first (a run started with `init_from`
    counts from its own first iteration; a resumed run goes on where it stopped)."""
    fade_iterations: int = ranged(0, AT_LEAST_0)
    """Iterations over which the strength falls linearly from 1 to 0 after the hold (0: it
    stops at once); the strength is logged as `Train/balance_assist`."""

    def scale(self, iteration: int) -> float:
        """Strength at a PPO iteration (0-based), 1 = full."""
        if self.torque <= 0.0 and self.damping <= 0.0:
            return 0.0
        if iteration < self.hold_iterations:
            return 1.0
        if self.fade_iterations <= 0:
            return 0.0
        return max(0.0, 1.0 - (iteration - self.hold_iterations) / self.fade_iterations)


@dataclass(frozen=True)
class TrainCfg:
    max_iterations: int = ranged(1000, AT_LEAST_1)
    num_steps_per_env: int = ranged(32, AT_LEAST_1)
    save_interval: int = ranged(50, AT_LEAST_1)
    keep_checkpoints: KeepCheckpointsCfg = KeepCheckpointsCfg()
    learning_rate: float = ranged(0.0003, POSITIVE)
    schedule: Literal["fixed", "adaptive"] = "adaptive"
    desired_kl: float = ranged(0.01, POSITIVE)
    gamma: float = ranged(0.99, FRACTION)
    lam: float = ranged(0.95, FRACTION)
    clip_param: float = ranged(0.2, POSITIVE)
    entropy_coef: float = ranged(0.0, AT_LEAST_0)
    value_loss_coef: float = ranged(1.0, AT_LEAST_0)
    num_learning_epochs: int = ranged(5, AT_LEAST_1)
    num_mini_batches: int = ranged(4, AT_LEAST_1)
    max_grad_norm: float = ranged(1.0, POSITIVE)
    clipped_value_loss: bool = True
    """PPO's clipped value loss (rsl-rl's default); TokenHSI trains without (`clip_value: False`)."""
    init_from: str | None = None
    """Start from another run's weights: a run folder (its policy: the checkpoint it selected
    on validation trials, else its latest) or a checkpoint file. Policy, critic, their
    normalisers and the discriminators are loaded; the optimiser and the iteration count start
    afresh (the progressive protocol: docs/PROTOCOL.md)."""
    init_action_std: float | None = ranged(None, POSITIVE)
    """With `init_from`: the action std the policy starts with, replacing the loaded one (null
    keeps it). At the learning rates a later stage runs at (1e-5, where rsl-rl's adaptive
    schedule holds it) the std parameter moves by ~1e-5 per step, so a stage keeps its source's
    exploration noise for good: the puppet's 1.0 (2 m/s of root speed per unit) made every
    Carry policy drop a held box within a few steps."""
    init_action_mean: dict[str, float] = field(default_factory=dict)
    """With `init_from`: named actions of the character (the puppet's `grasp`) whose mean
    starts at the given value in every state (their row of the policy's output layer zeroed,
    its bias set to the value). An action that had no effect in the source task (the grasp in
    Follow, which has nothing to hold) got only noise from PPO's gradient, so its mean is
    whatever that drift left: -0.6 at the box in one Follow cell, where Carry's exploration
    at std 0.3 never asked for a grasp and Carry scored 0.175; about +0.1 in an earlier one."""
    init_action_mean_choices: tuple[dict[str, float], ...] = ()
    """With `init_from`, instead of `init_action_mean`: starting action means to choose from,
    each written as `init_action_mean` is. Before training, the loaded policy (mean actions,
    unchanged) plays `init_choice_trials` validation trials of the run's task with each, in an
    evaluation env of its own seed (not the evaluation's), and the run starts from the one
    with the highest LH mean (the first on a tie). Why: which arm pose lets a Follow policy
    reach the box depends on where that policy holds its arms, so one fixed pose favours some
    models and handicaps others (results/laptop/NOTEBOOK.md, "the stage's starting point")."""
    init_choice_trials: int = ranged(50, AT_LEAST_1)
    """Validation trials per entry of `init_action_mean_choices`."""
    select_checkpoint_trials: int = ranged(0, AT_LEAST_0)
    """When > 0: after training, every checkpoint the run kept (`save_interval`,
    `keep_checkpoints`) plays this many validation trials of the run's task (an evaluation env
    of its own seed, the same trials for each), and the best (highest LH mean; the newest
    on a tie) becomes the run's policy, named in selection.json: evaluation, play, export and a
    later stage's `init_from` use it; resuming trains on from the newest and chooses again.
    Why: a later stage of the protocol peaks and then drifts; three Carry runs from one start
    scored 0.885, 0.86 and 0.92 after 20 iterations, 0.805, 0.68 and 0.735 after 50
    (results/laptop/NOTEBOOK.md). 0: the newest checkpoint is the policy."""
    init_normalizers: Literal["merge", "restart", "keep"] = "merge"
    """With `init_from`: `merge` (default) keeps the source's observation statistics for the
    inputs it saw vary and takes this run's task's (from its first update) for those it never
    saw vary; `restart` starts them all afresh on this task (the first rollout sets them);
    `keep` continues the source's. Kept statistics break a later stage of the protocol: an
    input the source task never varied (Carry's box, Follow's empty height map) has variance 0
    there and would be scaled by rsl-rl's 1/eps = 100 for hundreds of iterations (the source's
    sample count outweighs the new task's). Restarted ones change what the source policy does
    with the inputs it learned from."""
    init_at_random_ep_len: bool = True
    """Start training, and a resumed run's training, with each environment at a random step of
    its first episode (rsl-rl's `init_at_random_ep_len`, as IsaacLab and legged_gym train), so
    that episodes end at different iterations. Off, all environments start together and,
    where nothing ends an episode early (Carry's 1200 steps = 37 PPO iterations of 32 steps),
    every iteration's batch comes from one phase of the same episodes: the approach to the box
    only in the first of each 37 iterations."""
    critic_warmup_iterations: int = ranged(0, AT_LEAST_0)
    """The first iterations of this run train the critic alone, at
    `critic_warmup_learning_rate`: the policy and every parameter it shares with the critic stay
    as they are (no PPO step on them, no auxiliary or teacher loss), so that a stage started
    from another task's run (`init_from`) has values of its own task before its advantages move
    the policy. At a later stage's learning rate (1e-5) the critic, which shares PPO's
    optimiser, would otherwise fit the new rewards no faster than the policy moves."""
    critic_warmup_learning_rate: float = ranged(1.0e-3, POSITIVE)
    """Learning rate of the critic-only iterations (`critic_warmup_iterations`)."""
    reuse_frozen_features: bool = True
    """While DETACH's encoders are frozen (stage 2), run them once per update over the rollout
    and let every mini-batch read their outputs, instead of running them again in each of PPO's
    mini-batches and the auxiliary pass. The same method (equal up to float summation order;
    a test holds it); off only to measure the difference (benchmarks/bench_iteration_split.py)."""
    per_objective_advantage_norm: bool = False
    """With a multi-head critic (CML), normalise the advantage of each objective before their
    weighted sum; otherwise the weighted sum is normalised as one."""
    amp: AmpCfg = AmpCfg()
    balance_assist: BalanceAssistCfg = BalanceAssistCfg()
    clone_start: CloneStartCfg = CloneStartCfg()
    stages: StagesCfg = StagesCfg()
    teachers: dict[str, str] = field(default_factory=dict)
    """Kickstarting (`detach.train.teachers`): skill -> a run folder or checkpoint whose policy
    the student's mean action is pulled toward on that skill's steps, beside PPO, or `oracle`
    (the scripted oracle, a scriptable character only); empty = off."""
    teacher_weight: float = ranged(1.0, AT_LEAST_0)
    """Weight of the teachers' loss (mean squared action difference per step)."""
    teacher_only: bool = False
    """With teachers: distil them alone (PPO collects the student's rollouts but does not
    update; the critic and the rewards do not train the policy)."""
    action_bound_coef: float = ranged(0.0, AT_LEAST_0)
    """Weight of a penalty on mean actions beyond +-1.1 (`detach.train.action_bounds`; TokenHSI
    trains with 10); 0 = off."""
    torch_threads: int = ranged(0, AT_LEAST_0)
    """torch CPU threads of training, evaluation and play; 0 keeps torch's default (one per core,
    or OMP_NUM_THREADS). Set 1 when two runs share the cores."""
    logger: Literal["none", "tensorboard", "wandb"] = "none"
    """Where the metrics go besides log.mcap, through rsl-rl's own writers into the run folder:
    `tensorboard` (event files), `wandb` (Weights & Biases, the `[wandb]` extra; `WANDB_MODE=offline`
    keeps it on disk)."""
    wandb_project: str = "detach"
    """The W&B project of `logger: wandb` (the run's name is its folder's)."""
    check_for_nan: bool = True
    """rsl-rl's check: a NaN or infinity in the observations, rewards, dones, actions or losses
    stops the run (status failed, naming the iteration, step and environments)."""


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs; `detach.config.dump` writes it, `load_run_config` reads it back."""

    task_name: str
    model_name: str
    seed: int = field(metadata={RANGE: Range(0, 2**32 - 1)})
    device: str
    task: TaskCfg
    sim: SimCfg
    env: EnvCfg
    rewards: RewardsCfg
    eval: EvalCfg
    model: ModelCfg
    train: TrainCfg
    origin: ConfigOrigin = field(default_factory=ConfigOrigin, compare=False, repr=False,
                                 metadata={"dump": False})
    """File and line of every value (errors found after loading still point at them)."""
