"""`sim.compile`: the env's own tensor work of a step, run as `torch.compile` graphs, gives the
eager step's results: observations, rewards, dones, resets and the training log, with episodes
that end by timeout and by termination along the way. Slow: compiling the three graphs takes
~20-60 s (minutes on a cold cache)."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest
import torch

from detach.config import resolve
from detach.envs.lh_env import make_env

ROOT = Path(__file__).resolve().parents[1]
N = 8

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def inductor() -> None:
    """Skip where torch.compile cannot build CPU kernels (no C++ compiler or headers)."""
    if not (shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")):
        pytest.skip("torch.compile on a CPU needs a C++ compiler")
    try:
        torch.compile(lambda x: x * 2.0 + 1.0, dynamic=False)(torch.ones(3))
    except Exception as exc:  # noqa: BLE001 - any failure to build means no compiled path here
        pytest.skip(f"torch.compile cannot build CPU kernels here: {type(exc).__name__}: {exc}"[:300])


@pytest.mark.parametrize(("task", "character"), [("lh3", "humanoid"), ("lh1", "puppet")])
def test_the_compiled_step_gives_the_eager_steps_results(task: str, character: str, inductor: None) -> None:
    torch._dynamo.reset()  # the other parametrisation's graphs: a new env's would count as recompiles
    with torch._dynamo.config.patch(error_on_recompile=True):  # each graph compiles once (it compiled
        _compare_steps(task, character)                       # twice: caches and skill state made late)


def _compare_steps(task: str, character: str) -> None:
    envs = [make_env(resolve(str(ROOT / f"configs/tasks/{task}.yaml"), "mlp",
                             [f"env.character={character}", f"sim.compile={compiled}", "sim.nthread=1",
                              "env.episode_length=25"]), num_envs=N, verbose=False, seed=3)
            for compiled in (False, True)]
    eager, compiled = envs
    torch.testing.assert_close(compiled.obs["critic"], eager.obs["critic"])
    gen = torch.Generator().manual_seed(0)
    ended = 0
    for _ in range(60):
        actions = torch.rand(N, eager.num_actions, generator=gen) * 2 - 1
        (obs_e, rew_e, done_e, ext_e), (obs_c, rew_c, done_c, ext_c) = eager.step(actions), compiled.step(actions)
        assert torch.equal(done_c, done_e)
        assert torch.equal(ext_c["time_outs"], ext_e["time_outs"])
        torch.testing.assert_close(rew_c, rew_e, atol=1e-4, rtol=1e-4)
        for group in obs_e.keys():
            torch.testing.assert_close(obs_c[group], obs_e[group], atol=1e-4, rtol=1e-4, msg=group)
        assert torch.equal(compiled.tracker.subtask, eager.tracker.subtask)
        # the eager step leaves out the terms of skills no env is on (free to know on a CPU);
        # the compiled one logs them as NaN, which the training log skips (as on a GPU)
        assert set(ext_e["log"]) <= set(ext_c["log"])
        for key, value in ext_e["log"].items():
            torch.testing.assert_close(ext_c["log"][key], value, atol=1e-4, rtol=1e-4, equal_nan=True, msg=key)
        extra = set(ext_c["log"]) - set(ext_e["log"])
        assert all(math.isnan(float(ext_c["log"][k])) for k in extra), extra
        ended += int(done_e.sum())
    assert ended >= N  # every env has been reset at least once on average
