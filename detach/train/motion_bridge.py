"""The motion library seen from training: AMP reference windows and reference-state resets.

Reference windows are featurised with the env's own `amp_frame` (the single definition of
an AMP frame), so the discriminator compares like with like. With task-specific
discrimination a window's skill one-hot says which skill's clips (`Skill.motion_labels`) it
was drawn from. As in TokenHSI, the skills drawn are those of the run's plan that have clips,
with the weights of `train.amp.skill_weights` (its skillDiscProb, pooled per skill).
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import torch
import torch.nn.functional as F

from detach.character.body import DOF_NAMES, KEY_BODIES
from detach.config.schema import RunConfig
from detach.envs.observations import AMP_DIM, NUM_DOF, amp_frame
from detach.motion import MotionLib, MotionState
from detach.motion.labels import MOTION_LABELS
from detach.skills import canonical_name, run_skills, skill_class
from detach.torch_math import heading_matrix, yaw_of


def amp_features(state: MotionState) -> torch.Tensor:
    """MotionState with batch shape [n, steps] -> flattened AMP windows [n, steps * d]."""
    n, steps = state.root_pos.shape[:2]
    flat = state.reshape_batch(n * steps)
    frames = amp_frame(flat.root_pos, flat.root_quat, flat.root_lin_vel, flat.root_ang_vel,
                       flat.dof_pos, flat.dof_vel, flat.key_body_pos)
    return frames.reshape(n, -1)


def skill_draw_weights(plan: Sequence[str], with_clips: Sequence[str],
                       weights: Mapping[str, float]) -> dict[str, float]:
    """{skill: probability} of drawing a reference window of each skill: the plan's skills that
    have clips, weighted by `weights` (a skill it does not list gets the mean of those it does;
    none listed = uniform), normalised. Falls back to every skill with clips when none of the
    plan's has any (a plug-in skill without clips)."""
    chosen = [s for s in dict.fromkeys(plan) if s in with_clips] or list(with_clips)
    if not chosen:
        raise ValueError("the motion library has no clip for any skill; AMP needs reference motion")
    default = sum(weights.values()) / len(weights) if weights else 1.0
    raw = {s: float(weights.get(s, default)) for s in chosen}
    total = sum(raw.values())
    if total <= 0:
        raise ValueError(f"train.amp.skill_weights gives every skill of the plan ({', '.join(chosen)}) weight 0")
    return {s: w / total for s, w in raw.items()}


def amp_reference_sampler(lib: MotionLib, steps: int, dt: float, conditional: bool = True,
                          device: str | torch.device = "cpu", plan: Sequence[str] = (),
                          weights: Mapping[str, float] | None = None, skills: Sequence[str] | None = None,
                          ) -> Callable[[int], tuple[torch.Tensor, torch.Tensor]]:
    """fn(n) -> (AMP windows [n, steps * d], skill one-hot [n, number of the run's skills]);
    `skills`: the run's (`LHEnv.skills`; by default those of a config without env.skills)."""
    names = run_skills((), plan) if skills is None else tuple(skills)
    labels = [skill_class(name).motion_labels for name in names]
    with_clips = [name for name, group in zip(names, labels) if any(label in lib.skills_present for label in group)]
    draw = skill_draw_weights(plan, with_clips, weights or {})
    tasks = torch.tensor([names.index(s) for s in draw])
    probs = torch.tensor(list(draw.values()))

    def sample(n: int) -> tuple[torch.Tensor, torch.Tensor]:
        if conditional:
            picks = tasks[torch.multinomial(probs, n, replacement=True)]
            parts, onehots = [], []
            for task in picks.unique().tolist():
                k = int((picks == task).sum())
                _ids, state = lib.sample_windows(k, steps=steps, dt=dt, skills=labels[task])
                parts.append(amp_features(state))
                onehots.append(F.one_hot(torch.full((k,), task), len(names)).float())
            windows, cond = torch.cat(parts), torch.cat(onehots)
        else:
            _ids, state = lib.sample_windows(n, steps=steps, dt=dt)
            windows, cond = amp_features(state), torch.zeros(n, len(names))
        return windows.to(device), cond.to(device)

    return sample


def motion_label_weights(cfg: RunConfig) -> dict[str, float]:
    """The motion library's label weights from `train.amp.label_weights`: a label it leaves
    out weighs 1, so an empty mapping is the library's default (uniform over labels)."""
    given = cfg.train.amp.label_weights
    return {label: float(given.get(label, 1.0)) for label in MOTION_LABELS}


def start_clip_labels(cfg: RunConfig) -> tuple[str, ...] | None:
    """The motion labels reference-state starts draw from (`env.init_clips`): the first
    subtask's skill's, every label (`prop_free`: the sampler then keeps the clips without a
    prop), or None for every clip."""
    if cfg.env.init_clips == "all":
        return None
    if cfg.env.init_clips == "prop_free":
        return MOTION_LABELS
    return skill_class(canonical_name(cfg.task.plan[0])).motion_labels


def start_clip_probs(lib: MotionLib, labels: Sequence[str] | None = None) -> torch.Tensor:
    """[C] probability that a reference-state start is drawn from each clip.

    `labels`: only clips with these motion labels that need no prop (`meta["props"]`: a step
    or seat the motion stands or sits on, which the env does not have under a start), with the
    library's label weights renormalised over them; None: every clip."""
    probs = lib.clip_probs(None)
    if labels is None:
        return probs
    keep = torch.tensor([c.skill in labels and not c.meta.get("props") for c in lib.clips], device=probs.device)
    if keep.any():
        probs = torch.where(keep, lib.clip_probs([s for s in labels if s in lib.skills_present]), 0.0)
    if not keep.any() or probs.sum() <= 0:
        raise ValueError(f"reference-state starts: no clip labelled {sorted(labels)} without a prop "
                         f"and with a positive weight among the {lib.num_clips} clips")
    return probs / probs.sum()


def reset_reference_sampler(lib: MotionLib, labels: Sequence[str] | None = None,
                            drawn: dict[str, torch.Tensor] | None = None) -> Callable[[int, torch.Generator], dict]:
    """Reference-state initialisation source in the format `detach.envs.resets` expects,
    drawing clips by `start_clip_probs(lib, labels)`. `drawn`, if given, receives the clip
    `ids` and `times` of the latest draw (`detach.train.clip_clone` plays the clips on)."""
    probs = start_clip_probs(lib, labels)
    own: list[torch.Generator] = []

    def sample(n: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
        if generator.device.type != lib.device.type:
            # the env's generator on a GPU, the clips on the CPU: a CPU generator seeded once from it
            if not own:
                seed = int(torch.randint(2**62, (1,), generator=generator, device=generator.device))
                own.append(torch.Generator(device=lib.device).manual_seed(seed))
            generator = own[0]
        ids = torch.multinomial(probs, n, replacement=True, generator=generator)
        times = lib.sample_times(ids, generator=generator)
        if drawn is not None:
            drawn["ids"], drawn["times"] = ids, times
        s = lib.state(ids, times)
        R = heading_matrix(yaw_of(s.root_quat))
        return {"root_height": s.root_pos[:, 2], "root_quat": s.root_quat,
                "dof_pos": s.dof_pos, "dof_vel": s.dof_vel,
                "root_lin_vel": (s.root_lin_vel[:, None] @ R)[:, 0],
                "root_ang_vel": (s.root_ang_vel[:, None] @ R)[:, 0]}

    return sample


def amp_part_indices(parts: tuple[str, ...] | list[str], steps: int) -> dict[str, list[int]]:
    """Feature indices of an AMP window per body part, for CML's body-part discriminators.

    An AMP frame (`detach.envs.observations`) is: root height (1), root rotation (6), root
    linear and angular velocity (6), hinge positions (32) and velocities (32), hand and foot
    positions (12). Every part sees the root features; `upper` the abdomen, neck, shoulder
    and elbow hinges and the hands; `lower` the hip, knee and ankle hinges and the feet.
    """
    upper_joints = ("abdomen", "neck", "right_shoulder", "right_elbow", "left_shoulder",
                    "left_elbow")
    root = list(range(13))
    dof_base, vel_base, key_base = 13, 13 + NUM_DOF, 13 + 2 * NUM_DOF
    out: dict[str, list[int]] = {}
    for part in parts:
        if part not in ("upper", "lower"):
            raise ValueError(f"unknown AMP body part {part!r}; expected 'upper' or 'lower'")
        want_upper = part == "upper"
        dofs = [i for i, name in enumerate(DOF_NAMES)
                if name.rsplit("_", 1)[0].startswith(upper_joints) == want_upper]
        keys = [i for i, name in enumerate(KEY_BODIES) if name.endswith("hand") == want_upper]
        frame = root + [dof_base + i for i in dofs] + [vel_base + i for i in dofs]
        frame += [key_base + 3 * k + j for k in keys for j in range(3)]
        out[part] = [step * AMP_DIM + i for step in range(steps) for i in frame]
    return out
