"""Does `torch.compile` shrink the env's own work enough for the env/raw goal (bench_env.py)?

Times the two widest observation frames of one LH3 humanoid step (`self_frame` and
`env_frame` of `detach.envs.observations`, ~90 small eager ops together) eager and compiled
by inductor, with its default Python wrapper and with `cpp_wrapper`, side by side in one
process on the same inputs, and prints each one's time per call and its ratio to eager.
Compiling is paid once per process here (tens of seconds cold, seconds from inductor's cache).

    python benchmarks/bench_obs_compile.py [--n 64] [--calls 500]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def frames_inputs(n: int) -> tuple:
    """The inputs of both frames from a humanoid LH3 env after 20 standing steps."""
    from detach import make_env, observations as O, resolve
    from scene_builder.assets import ensure_assets

    cfg = resolve(str(ROOT / "configs/tasks/lh3.yaml"), "mlp", ["env.character=humanoid"])
    ensure_assets(cfg.task)
    env = make_env(cfg, num_envs=n, verbose=False)
    act = torch.zeros(n, env.num_actions)
    for _ in range(20):
        env.step(act)
    ctx = env.context(env._read())
    st, ob = ctx.state, env.observations
    R = O.heading_matrix(O.yaw_of(st.root_quat))
    hmap = O.local_height_map(st.root_pos, R, ob.hm_offsets, ob.raster, st.obj_pos[:, ob.dyn],
                              st.obj_quat[:, ob.dyn], ob.obj_half[ob.dyn])
    ahead = env.services.trajectory.reference(env.steps, ob.sample_times)
    return (st.root_pos, R, st.body_pos, st.body_quat, st.body_lin, st.body_ang, st.dof_pos, st.dof_vel,
            ctx.goal, ahead, env.tracker.follows_path[ctx.skill], ctx.has_obj, ctx.obj_pos, ctx.obj_quat,
            ctx.obj_half, hmap)


def both_frames(root_pos, R, body_pos, body_quat, body_lin, body_ang, dof_pos, dof_vel, goal, ahead,
                follows, has_obj, obj_pos, obj_quat, obj_half, hmap):
    from detach import observations as O

    return (O.self_frame(body_pos, body_quat, body_lin, body_ang, dof_pos, dof_vel, R),
            O.env_frame(root_pos, R, goal, ahead, follows, has_obj, obj_pos, obj_quat, obj_half, hmap))


def per_call_us(fn, args: tuple, calls: int) -> float:
    for _ in range(20):
        fn(*args)
    t = time.perf_counter()
    for _ in range(calls):
        fn(*args)
    return (time.perf_counter() - t) / calls * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=64, help="envs (default 64, bench_env.py's goal size)")
    ap.add_argument("--calls", type=int, default=500)
    args = ap.parse_args()
    torch.set_num_threads(1)
    import torch._inductor.config as inductor_cfg

    inputs = frames_inputs(args.n)
    variants = {"eager": both_frames}
    compile_s = {}
    for name, cpp in (("compiled", False), ("compiled, cpp_wrapper", True)):
        torch._dynamo.reset()
        inductor_cfg.cpp_wrapper = cpp
        fn = torch.compile(both_frames, dynamic=False)
        t = time.perf_counter()
        out = fn(*inputs)
        compile_s[name] = time.perf_counter() - t
        ref = both_frames(*inputs)
        assert all(torch.allclose(a, b, atol=1e-5) for a, b in zip(out, ref)), f"{name} differs from eager"
        variants[name] = fn
    times = {name: per_call_us(fn, inputs, args.calls) for name, fn in variants.items()}
    print(f"{os.cpu_count()} cores, torch {torch.__version__}, 1 thread, N = {args.n}: self_frame + env_frame")
    print(f"{'variant':<24}{'us per call':>12}{'vs eager':>10}{'compile s':>11}")
    for name, us in times.items():
        print(f"{name:<24}{us:>12.0f}{times['eager'] / us:>9.2f}x{compile_s.get(name, 0.0):>11.1f}")


if __name__ == "__main__":
    main()
