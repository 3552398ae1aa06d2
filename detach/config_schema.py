"""Typed, frozen sections of a run configuration.

Every YAML section maps onto one dataclass below; `detach.config` validates raw YAML into
these types, so the rest of the code never sees an unchecked dict. Units: metres, seconds,
radians; positions are world frame unless a field says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

SKILLS: tuple[str, ...] = ("traj", "carry", "climb", "sit")
"""Skill vocabulary of the paper's plans; `task` one-hot observations use this order."""

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
    plan: tuple[Literal["traj", "carry", "climb", "sit"], ...] = ("traj",)
    target_object: tuple[int, ...] = (0,)
    sample_target_from: tuple[str, ...] = ("traj_0",)
    """`traj_K` (trajectory K; procedural when K is `rand`), `tarpos_K`, `scene_K`."""


@dataclass(frozen=True)
class SimCfg:
    num_envs: int = 64
    physics_dt: float = 1.0 / 120.0
    substeps: int = 4
    """Physics steps per control step: 1/120 s x 4 = 30 Hz control."""
    nthread: int = 0
    """Threads stepping the batch; 0 = all cores."""
    friction: float = 1.0
    solver_iterations: int = 4
    sleep: bool = True
    """Let resting objects sleep (MuJoCo islands): untouched boxes and furniture cost nothing
    until something touches them (~35% less physics per step in the LH scenes)."""


@dataclass(frozen=True)
class HeightMapCfg:
    enabled: bool = True
    grid: int = 25
    spacing: float = 0.1
    camera_height: float = 10.0


@dataclass(frozen=True)
class TrajectoryGenCfg:
    """Procedural reference trajectories for `follow` (paper: Data Generation Parameters)."""

    num_samples: int = 10
    sample_dt: float = 0.5
    speed_min: float = 1.4
    speed_max: float = 1.5
    accel_max: float = 2.0
    sharp_turn_prob: float = 0.02
    sharp_turn_angle: float = 1.57
    num_verts: int = 101
    """Vertices of one generated trajectory (covers a whole episode)."""


CHARACTER_ACTION_STD: dict[str, float] = {"humanoid": 0.1, "puppet": 1.0}
"""Initial policy action std per character (`model.init_noise_std: null` picks it). Measured
(benchmarks/RESULTS.md): std 1 makes the humanoid's PD targets jump by its whole joint range,
the power penalty then dominates and episodes end in ~37 steps; the puppet, whose task rides on
three root-velocity actions, learns fastest with 1 (0.5 and 0.2 were slower)."""


def action_std(init_noise_std: float | None, character: str) -> float:
    """`model.init_noise_std`, or the character's std when it is None (null in YAML)."""
    return CHARACTER_ACTION_STD[character] if init_noise_std is None else init_noise_std


@dataclass(frozen=True)
class EnvCfg:
    character: Literal["humanoid", "puppet"] = "humanoid"
    episode_length: int = 1200
    success_threshold: float = 0.3
    max_transition_steps: int = 60
    termination_height: float = 0.15
    traj_fail_distance: float = 4.0
    init: Literal["default", "random", "mixed"] = "mixed"
    mixed_init_prob: float = 0.5
    history_self: int = 5
    history_env: int = 5
    amp_obs_steps: int = 10
    iet: Literal["none", "last_subtask", "all"] = "last_subtask"
    task_specific_discrimination: bool = True
    height_map: HeightMapCfg = HeightMapCfg()
    trajectory: TrajectoryGenCfg = TrajectoryGenCfg()
    climb_pelvis_height: float = 0.9
    """Climb target = the object's climb point (top surface) raised by this much (m): a
    standing pelvis; `climb` succeeds with the pelvis at or above it (within the threshold)."""
    follow_on_path_frac: float = 0.9
    """A follow subtask succeeds when its end is reached and the pelvis was within
    `success_threshold` of the path (XY) for at least this fraction of its steps."""


@dataclass(frozen=True)
class RewardsCfg:
    power_coeff: float = 0.0005
    dyn_obj_speed_penalty_coeff: float = 1.0
    dyn_obj_speed_threshold: float = 1.5
    decoupling_mask_strength: float = 0.3
    terms: dict[str, float] = field(default_factory=dict)
    """Weights of named reward terms (`<skill>/<term>`); printed as a table at start-up."""


@dataclass(frozen=True)
class EvalCfg:
    trials: int = 100
    max_transition_steps: int = 20
    num_envs: int = 16
    confidence: float = 0.95


@dataclass(frozen=True)
class EnvEncoderCfg:
    kernel_sizes: tuple[int, ...] = (1, 3, 5)
    channels: int = 64
    attn_heads: int = 4
    decoder_hidden: int = 256
    """Hidden width of Decoder_env (per-frame MLP z_env[t] -> env frame)."""


@dataclass(frozen=True)
class SelfEncoderCfg:
    hidden: int = 64
    layers: int = 1
    decoder_hidden: int = 256
    """Hidden width of Decoder_self (per-frame MLP z_self[t] -> self frame)."""
    predictor_hidden: int = 128
    """Hidden width of the temporal predictor f_pred."""


@dataclass(frozen=True)
class FusionCfg:
    cross_attn_heads: int = 8
    gate_hidden: tuple[int, ...] = (128, 64)
    num_experts: int = 4
    expert_hidden: tuple[int, ...] = (128, 64)


@dataclass(frozen=True)
class RegularizerCfg:
    lambda_quality: float = 0.1
    lambda_disentangle: float = 0.01
    lambda_r1: float = 0.01
    lambda_r2: float = 0.01
    lambda_r3: float = 0.001
    lambda_temporal: float = 0.001
    lambda_semantic: float = 0.01
    lambda_decouple: float = 0.01
    """Weight of R_decouple = ||Corr(z_env, z_self)||_F^2 in the joint stage."""
    semantic_env_weight: float = 1.0
    """alpha of R_semantic (env reconstruction term)."""
    semantic_self_weight: float = 1.0
    """beta of R_semantic (self reconstruction term)."""
    r3_mode: Literal["distance", "cosine"] = "distance"
    """R3 as printed in the paper (sum of squared distances between fusion outputs, which
    pulls them together) or `cosine` (mean squared cosine similarity, which pushes them apart,
    the stated intent "fusion diversity")."""


@dataclass(frozen=True)
class ModelCfg:
    """One network of the study; `kind` picks the class, the other fields its sizes."""

    kind: Literal["detach", "tokenhsi", "cml", "mlp"] = "mlp"
    d_model: int = 64
    num_layers: int = 4
    num_heads: int = 8
    ff_dim: int = 256
    adapter_units: tuple[int, ...] = (1024, 512)
    activation: str = "elu"
    use_env_encoder: bool = True
    use_self_encoder: bool = True
    env_encoder: EnvEncoderCfg = EnvEncoderCfg()
    self_encoder: SelfEncoderCfg = SelfEncoderCfg()
    fusion: FusionCfg = FusionCfg()
    regularizers: RegularizerCfg = RegularizerCfg()
    tokenizer_units: tuple[int, ...] = (256, 128)
    gru_hidden: int = 256
    critic_objectives: tuple[str, ...] = ("task",)
    """Value heads of a multi-head critic (CML): one per reward objective."""
    init_noise_std: float | None = None
    """Initial action std of the Gaussian policy; None = the character's
    (`CHARACTER_ACTION_STD`), filled in when a run config is resolved."""
    history_frames: int = 0
    """MLP only: the newest frames of each history group the network reads (0 = all T)."""
    shared_trunk: bool = False
    """The critic reads the actor's trunk: its value head sees [h; privileged groups] (the
    paper's V(s) = ValueHead(h_transformer)), so one trunk is trained and run per update."""
    obs_normalization: bool = True
    """Running mean/std normalisation of the concatenated observation groups (rsl-rl's
    EmpiricalNormalization) before the network; reconstruction targets are normalised too."""


@dataclass(frozen=True)
class AmpCfg:
    enabled: bool = True
    task_reward_weight: float = 0.5
    style_reward_weight: float = 0.5
    disc_hidden: tuple[int, ...] = (1024, 512)
    objective: Literal["lsgan", "logistic"] = "lsgan"
    grad_penalty: float = 5.0
    logit_reg: float = 0.01
    weight_decay: float = 0.0001
    replay_size: int = 100000
    batch_size: int = 512
    learning_rate: float = 0.0001
    body_parts: tuple[str, ...] = ()
    """Body-part discriminators (CML): e.g. (upper, lower); empty = one whole-body one."""


@dataclass(frozen=True)
class StagesCfg:
    """DETACH's progressive protocol, in PPO iterations (0 disables a stage)."""

    pretrain: int = 0
    fusion: int = 0
    joint: int = 0


@dataclass(frozen=True)
class TrainCfg:
    max_iterations: int = 1000
    num_steps_per_env: int = 32
    save_interval: int = 50
    learning_rate: float = 0.0003
    schedule: Literal["fixed", "adaptive"] = "adaptive"
    desired_kl: float = 0.01
    gamma: float = 0.99
    lam: float = 0.95
    clip_param: float = 0.2
    entropy_coef: float = 0.0
    value_loss_coef: float = 1.0
    num_learning_epochs: int = 5
    num_mini_batches: int = 4
    max_grad_norm: float = 1.0
    per_objective_advantage_norm: bool = False
    amp: AmpCfg = AmpCfg()
    stages: StagesCfg = StagesCfg()
    torch_threads: int = 0
    """torch CPU threads; 0 keeps torch's default (one per core, or OMP_NUM_THREADS)."""


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs; `detach.config.dump` writes it, `load_run_config` reads it back."""

    task_name: str
    model_name: str
    seed: int
    device: str
    task: TaskCfg
    sim: SimCfg
    env: EnvCfg
    rewards: RewardsCfg
    eval: EvalCfg
    model: ModelCfg
    train: TrainCfg
