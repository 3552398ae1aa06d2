"""The environment step reads the device on the host once, to learn which episodes ended (as
IsaacLab's and mjlab's envs do), so that on a GPU it queues its kernels without waiting for
them. On a CPU, `deferred_reads` makes the env take the accelerator's path, a
`TorchDispatchMode` lists the aten ops that read a tensor's value on the host, and a
`TorchFunctionMode` the calls that copy host data to the device on an accelerator (a copy
from pageable host memory waits for the stream too: on an H200, before these were counted,
a humanoid LH1 step made ~19 such waits, measured with `torch.cuda.set_sync_debug_mode`)."""

from __future__ import annotations

import traceback
from pathlib import Path

import pytest
import torch
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode

from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.envs.oracle import Oracle
from detach.host_sync import deferred_reads, may_any
from detach.train.start_library import make_training_env

ROOT = Path(__file__).resolve().parents[1]
READS = {"_local_scalar_dense", "nonzero", "is_nonzero", "masked_select", "_unique", "_unique2",
         "unique_dim", "unique_consecutive"}
"""aten ops that read values on the host (`.item()`, `bool()`, `nonzero`, data-sized outputs)."""
INDEXING = {"index", "index_put", "index_put_", "_index_put_impl_"}
"""...and these with a bool index, which select by `nonzero` inside."""


class HostReads(TorchDispatchMode):
    """Records (file, function) of the detach code that issued each host-reading op."""

    def __init__(self) -> None:
        super().__init__()
        self.sites: list[tuple[str, str]] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.__name__.split(".")[0]
        bool_index = name in INDEXING and len(args) > 1 and any(
            isinstance(t, torch.Tensor) and t.dtype == torch.bool for t in args[1])
        if name in READS or bool_index:
            self.sites.append(_detach_site())
        return func(*args, **(kwargs or {}))


def _detach_site() -> tuple[str, str]:
    ours = [f for f in traceback.extract_stack() if "/detach/" in f.filename]
    return (ours[-1].filename.split("/detach/")[-1], ours[-1].name) if ours else ("?", "?")


def _has_list(index) -> bool:
    parts = index if isinstance(index, tuple) else (index,)
    return any(isinstance(p, list) for p in parts)


def _has_tensor(index) -> bool:
    parts = index if isinstance(index, tuple) else (index,)
    return any(isinstance(p, torch.Tensor) for p in parts)


class HostCopies(TorchFunctionMode):
    """Records (file, function) of each call that, on an accelerator, copies host data to the
    device: a tensor made from Python or NumPy data, an index given as a Python list, or a
    Python number written through a tensor index (`t[ids] = 0`: index_put_ takes the number
    as a host tensor; `index_fill_` takes it as a kernel argument)."""

    def __init__(self) -> None:
        super().__init__()
        self.sites: list[tuple[str, str]] = []

    def __torch_function__(self, func, types, args=(), kwargs=None):
        name = getattr(func, "__name__", "")
        copies = ((name in ("tensor", "as_tensor") and args and not isinstance(args[0], torch.Tensor))
                  or (name in ("__getitem__", "__setitem__") and _has_list(args[1]))
                  or (name == "__setitem__" and _has_tensor(args[1]) and isinstance(args[2], (bool, int, float))))
        site = _detach_site() if copies else None
        if copies and site != ("torch_math.py", "index_on"):  # made once per device, then cached
            self.sites.append(site)
        return func(*args, **(kwargs or {}))


def _env(task: str, *overrides: str, eval_mode: bool = True):
    cfg = resolve(ROOT / f"configs/tasks/{task}.yaml", "mlp", ["env.character=puppet", *overrides], seed=3)
    return make_env(cfg, num_envs=3, eval_mode=True, verbose=False) if eval_mode else \
        make_training_env(cfg, num_envs=3, verbose=False)


def test_may_any_reads_on_the_cpu_and_not_when_deferred() -> None:
    none = torch.zeros(4, dtype=torch.bool)
    assert may_any(none) is False and may_any(~none) is True
    with deferred_reads():
        assert may_any(none) is True
    assert may_any(none) is False


def _count_reads(env, policy, steps: int) -> tuple[set[tuple[str, str]], list[int], int]:
    """Step env under `deferred_reads`: (sites of every host read or host-to-device copy, their
    count per step, episodes ended)."""
    sites: set[tuple[str, str]] = set()
    per_step, ended = [], 0
    for _ in range(steps):
        actions = policy()
        reads, copies = HostReads(), HostCopies()
        with deferred_reads(), reads, copies:
            _obs, _rew, dones, _extras = env.step(actions)
        sites.update(reads.sites + copies.sites)
        per_step.append(len(reads.sites) + len(copies.sites))
        ended += int(dones.sum())
    return sites, per_step, ended


def test_every_step_reads_the_host_once() -> None:
    """The scripted oracle drives LH1 through every transition, a grasp and a release: each
    step makes exactly one host read, the reset gate in `step`."""
    torch.set_num_threads(1)
    env = _env("lh1", "env.episode_length=700")
    oracle, reached, grasped = Oracle(env), [], []

    def policy() -> torch.Tensor:
        reached.append(int(env.tracker.subtask.max()))
        grasped.append(int((env.character.held_object() >= 0).sum()))
        return oracle()

    sites, per_step, ended = _count_reads(env, policy, 720)
    assert sites == {("envs/lh_env.py", "step")} and set(per_step) == {1}
    assert max(reached) == 3 and max(grasped) > 0 and ended == env.num_envs  # every path was stepped


@pytest.mark.parametrize(("task", "overrides"), [
    ("carry", ("env.character=puppet", "env.mid_task_init_prob=0.6")),  # starts holding the box
    ("lh1", ("env.character=puppet", "env.subtask_start_prob=0.6")),  # starts at later subtasks
    ("lh1", ("env.character=humanoid",)),
])
def test_resets_add_no_host_read(task: str, overrides: tuple[str, ...]) -> None:
    torch.set_num_threads(1)
    cfg = resolve(ROOT / f"configs/tasks/{task}.yaml", "mlp", [*overrides, "env.init=mixed"], seed=3)
    env = make_training_env(cfg, num_envs=4, verbose=False)
    env.max_episode_length = 30  # end episodes often (the recording of later starts needed the full length)
    gen = torch.Generator().manual_seed(0)
    sites, per_step, ended = _count_reads(env, lambda: torch.rand(4, env.num_actions, generator=gen) * 2 - 1, 70)
    assert sites == {("envs/lh_env.py", "step")} and set(per_step) == {1}
    assert ended >= 8
    if "puppet" in overrides[0]:  # the mid-task or later-subtask starts were stepped
        assert bool(env.tracker.started_mid_task.any())


@pytest.mark.parametrize(("task", "start"), [("carry", "env.mid_task_init_prob=0.5"),
                                            ("lh1", "env.subtask_start_prob=0.5")])
def test_deferred_reads_change_no_result(task: str, start: str) -> None:
    """The accelerator's path (masks, idle work done) gives the CPU path's numbers exactly,
    through transitions, grasps, mid-task or later-subtask starts and resets. (Plans with
    procedural paths draw them for every env on that path, so their random streams differ.)"""
    torch.set_num_threads(1)
    over = ("env.episode_length=250", start, "env.init=mixed")
    a, b = _env(task, *over, eval_mode=False), _env(task, *over, eval_mode=False)
    oracle = Oracle(a)
    ended = late = 0
    for step in range(400):
        actions = oracle()
        obs_a, rew_a, done_a, _ = a.step(actions)
        with deferred_reads():
            obs_b, rew_b, done_b, _ = b.step(actions)
        ended += int(done_a.sum())
        late += int(a.tracker.started_mid_task.sum())
        assert torch.equal(done_a, done_b) and torch.equal(rew_a, rew_b), step
        for key in obs_a.keys():
            assert torch.equal(obs_a[key], obs_b[key]), (step, key)
    assert ended >= 3 and late > 0


@pytest.mark.parametrize("task", ["follow", "carry"])
def test_training_logs_skip_terms_no_env_was_paid(task: str) -> None:
    """Under deferred reads a reward term of a skill no env is on is a NaN mean, which the
    training log leaves out (`rollout_means`), as the CPU path leaves the term out."""
    from detach.train.runner import rollout_means

    env = _env(task, eval_mode=False)
    with deferred_reads():
        _, _, _, extras = env.step(torch.zeros(env.num_envs, env.num_actions))
    logs = {k: [torch.as_tensor(v, dtype=torch.float32).flatten()] for k, v in extras["log"].items()}
    means = rollout_means(logs)
    other = "carry" if task == "follow" else "follow"
    assert any(torch.isnan(v).all() for k, v in extras["log"].items() if k.startswith(f"Episode_Reward/{other}/"))
    assert not any(k.startswith(f"Episode_Reward/{other}/") for k in means)
    assert any(k.startswith(f"Episode_Reward/{task}/") for k in means)
