"""Subtask starts (`env.subtask_start_prob`, training only): a share of a long plan's training
episodes begins at a later subtask, from a state the scripted oracle was in when it began
that subtask.

Why: in LH1 (follow, carry, climb, sit) a policy that has not yet mastered the first subtasks
never reaches the last ones, so Climb and Sit learned inside the composition get no samples
until Follow and Carry are reliable, and an episode that fails early teaches nothing about
the rest. Starting some episodes at subtask k gives every subtask its share of samples from
the first iteration (the long-horizon counterpart of reference state initialisation).

The states are recorded once per training env, before it is built (the train layer's
`detach.train.start_library` hands them to it), by driving a second, small env of the same task
with `detach.envs.oracle.Oracle` through one episode each: whenever a transition
fires, the simulation state (qpos, qvel), the objects drawn for the plan and the object the
character holds are kept. A subtask the oracle never began cannot be started at; the env's
start-up line says how many states each subtask has. Needs a scriptable character (the
puppet); the humanoid has no oracle.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import torch

from detach.envs.oracle import Oracle

RECORD_ENVS = 16
"""Oracle episodes recorded per env construction (each gives at most one state per subtask)."""


@dataclass(frozen=True)
class SubtaskStarts:
    """M recorded states, each at the beginning of subtask `subtask[m]` (>= 1)."""

    subtask: torch.Tensor
    """[M] the subtask the state begins."""
    qpos: torch.Tensor
    """[M, nq]"""
    qvel: torch.Tensor
    """[M, nv]"""
    objects: torch.Tensor
    """[M, S] the object of every subtask (as drawn for the recorded episode)."""
    held: torch.Tensor
    """[M] slot of the movable object held (-1: none)."""
    root_pos: torch.Tensor
    """[M, 3]"""
    root_quat: torch.Tensor
    """[M, 4] (wxyz)"""
    held_pos: torch.Tensor
    """[M, 3] the held object's position (zeros when none)."""
    held_quat: torch.Tensor
    """[M, 4] its orientation (wxyz)."""

    def __len__(self) -> int:
        return len(self.subtask)

    def count(self, num_subtasks: int) -> dict[int, int]:
        """States per subtask index 1..num_subtasks-1."""
        return {k: int((self.subtask == k).sum()) for k in range(1, num_subtasks)}

    @cached_property
    def by_subtask(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(table [K, L], count [K]): the states of each of the K subtasks that have any, in
        the first count[k] places of row k. Made once, when the env is built (it reads the
        device), so that `draw` reads nothing."""
        kinds = torch.unique(self.subtask).tolist()
        rows = [(self.subtask == k).nonzero(as_tuple=False).squeeze(-1) for k in kinds]
        table = torch.zeros(len(rows), max(len(r) for r in rows), dtype=torch.long, device=self.subtask.device)
        for i, r in enumerate(rows):
            table[i, :len(r)] = r
        return table, torch.tensor([len(r) for r in rows], device=self.subtask.device)

    def draw(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """[n] indices of states, uniform over the subtasks that have any, then over their states
        (so a subtask with fewer recorded states is not started less often)."""
        table, count = self.by_subtask
        dev = table.device
        kind = torch.randint(len(count), (n,), generator=gen, device=gen.device).to(dev)
        u = torch.rand(n, generator=gen, device=gen.device).to(dev)
        return table[kind, torch.minimum((u * count[kind]).long(), count[kind] - 1)]


def record_subtask_starts(env) -> SubtaskStarts:
    """Drive `env` (an `LHEnv` of the task with subtask starts off) with the oracle until each of
    its envs has ended one episode or begun its last subtask (at most an episode length) and
    keep the state at every transition. The env is left mid-episode; it is meant to be thrown
    away."""
    oracle = Oracle(env)
    n, dev = env.num_envs, env.device
    finished = torch.zeros(n, dtype=torch.bool, device=dev)
    before = env.tracker.subtask.clone()
    dynamic = torch.as_tensor(env.scene.dynamic, dtype=torch.long, device=dev)
    kept: dict[str, list[torch.Tensor]] = {k: [] for k in SubtaskStarts.__dataclass_fields__}
    for _ in range(env.max_episode_length):
        _obs, _rew, dones, _extras = env.step(oracle())
        began = (env.tracker.subtask > before) & ~dones & ~finished
        finished |= dones
        before = env.tracker.subtask.clone()
        ids = began.nonzero(as_tuple=False).squeeze(-1)
        if len(ids):
            st = env.state
            held = env.character.held_object()[ids]
            obj = dynamic[held.clamp(min=0)] if len(dynamic) else torch.zeros_like(held)
            has = (held >= 0)[:, None]
            kept["subtask"].append(env.tracker.subtask[ids].clone())
            kept["qpos"].append(env.backend.qpos[ids].clone())
            kept["qvel"].append(env.backend.qvel[ids].clone())
            kept["objects"].append(env.tracker.objects[ids].clone())
            kept["held"].append(held.clone())
            kept["root_pos"].append(st.root_pos[ids].clone())
            kept["root_quat"].append(st.root_quat[ids].clone())
            kept["held_pos"].append(torch.where(has, st.obj_pos[ids, obj], 0.0))
            kept["held_quat"].append(torch.where(has, st.obj_quat[ids, obj], 0.0))
        if bool((finished | (before == env.tracker.num_subtasks - 1)).all()):
            break  # every episode has ended or begun its last subtask: nothing more to record
    if not kept["subtask"]:
        empty = {"subtask": torch.zeros(0, dtype=torch.long, device=dev)}
        return SubtaskStarts(**{k: empty.get(k, torch.zeros(0, device=dev)) for k in kept})
    return SubtaskStarts(**{k: torch.cat(v) for k, v in kept.items()})


def recording_summary(starts: SubtaskStarts, num_subtasks: int, seconds: float) -> str:
    counts = ", ".join(f"{k}: {c}" for k, c in starts.count(num_subtasks).items())
    return (f"subtask starts: the scripted oracle began subtasks {{{counts}}} in {RECORD_ENVS} episodes "
            f"({seconds:.1f} s)")
