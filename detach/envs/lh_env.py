"""The batched long-horizon HSI environment (rsl-rl-lib `VecEnv`).

N independent copies of one compiled scene run in a `PhysicsBackend`; everything else here —
plan progress, targets, rewards, terminations, resets, observations — is batched torch on
the env's device. Single-skill tasks are one-subtask plans.

Episode end: the pelvis below `termination_height` (fall), more than `traj_fail_distance`
from the trajectory's reference point during a traj subtask, the episode length, or (IET)
completion of the last subtask (`env.iet` = last_subtask; `all` behaves the same, since an
earlier subtask's completion starts the next one; `none` keeps the episode running). The last
two are time-outs (`extras["time_outs"]`) so PPO bootstraps them.

Actions: 32 hinge PD targets for the humanoid (`detach.envs.actions`); 37 for the puppet
(hinges, root velocity/height servos, grasp; `detach.envs.puppet`). Observations:
`detach.envs.observations`, sizes in `env.obs_spec`. Rewards: `detach.envs.rewards`.

What an evaluator reads (`progress()`; also `extras["episode_progress"]` at every step where
some episode ended, holding the finished episodes' values under `dones`): per env the
current subtask, per env and subtask `done` (transition fired), `score` (paper success, see
`detach.envs.success`), `grasped`, `start`/`end` (control steps since the episode start, -1
if not reached), `exec_time` (s), plus `lh_success`, `fell`, `traj_failed`, `length`.
"""

from __future__ import annotations

import math

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from detach.config_schema import SKILLS, RunConfig
from detach.envs import humanoid as H
from detach.envs import observations as O
from detach.envs import puppet as P
from detach.envs import success as S
from detach.envs.actions import pd_targets
from detach.envs.backend import MujocoBatchBackend
from detach.envs.obs_spec import ObsSpec
from detach.envs.plan import RAND, PlanTensors, compile_plan
from detach.envs.resets import ResetSampler
from detach.envs.rewards import RewardContext, RewardManager
from detach.envs.state import SceneIndex, SimState, read_state
from detach.envs.torch_math import heading_matrix, quat_conj, quat_mul, quat_rotate, yaw_of
from detach.envs.trajectories import distance_to_polyline, pad_to, random_trajectories, sample_at, time_polyline
from scene_builder.scene import compile_scene

FIXED_TRAJ_DT = 0.1
"""Vertex spacing in time (s) of YAML trajectories after timing them at the mean speed."""


class LHEnv(VecEnv):
    """See the module docstring; construct with `make_env`."""

    def __init__(self, cfg: RunConfig, num_envs: int | None = None, device: str | torch.device = "cpu",
                 eval_mode: bool = False, assets: dict | None = None, assets_root=None,
                 verbose: bool = True, seed: int | None = None) -> None:
        self.cfg = cfg
        ec, sc = cfg.env, cfg.sim
        self.device = torch.device(device)
        self.eval_mode = eval_mode
        self.character = ec.character
        self.num_envs = int(num_envs or (cfg.eval.num_envs if eval_mode else sc.num_envs))
        self.gen = torch.Generator().manual_seed(int(cfg.seed if seed is None else seed))
        self.model, self.scene = compile_scene(cfg.task, sc, self.character, assets, assets_root,
                                               camera_height=ec.height_map.camera_height)
        self.backend = MujocoBatchBackend(self.model, self.num_envs, sc.nthread, self.device)
        self.ix = SceneIndex.build(self.scene, self.model, self.device)
        self.substeps = int(sc.substeps)
        self.dt = sc.physics_dt * sc.substeps
        self.max_episode_length = int(ec.episode_length)
        self.max_transition_steps = int(cfg.eval.max_transition_steps if eval_mode else ec.max_transition_steps)
        self.threshold = float(ec.success_threshold)
        self.puppet = self.character == "puppet"
        self.num_actions = P.NUM_ACTIONS if self.puppet else H.NUM_DOF
        self.plan = compile_plan(cfg.task)
        self.pt = PlanTensors.build(self.plan, self.device)
        self.num_subtasks = len(self.plan)
        self.rewards = RewardManager(cfg.rewards)
        self.resets = ResetSampler(cfg, self.scene, self.model, self.gen, self.device)
        rng = torch.as_tensor(H.dof_ranges(), dtype=torch.float32, device=self.device)
        self.dof_lo, self.dof_hi = rng[:, 0], rng[:, 1]
        hm = ec.height_map
        self.hm_offsets = O.height_grid_offsets(hm.grid, hm.spacing, self.device)
        self.amp_idx = O.amp_index(self.ix.key.tolist()).to(self.device)
        r = self.scene.raster
        self.raster = O.Raster(torch.as_tensor(r.heights, device=self.device), r.origin, r.spacing)
        self._setup_trajectories()
        self.obs_spec = ObsSpec(
            self_steps=ec.history_self, self_dim=O.SELF_DIM, env_steps=ec.history_env,
            env_dim=O.env_dim(hm.grid), height_map_cells=hm.grid * hm.grid, num_skills=len(SKILLS),
            critic_dim=O.SELF_DIM + O.env_dim(hm.grid) + len(SKILLS) + O.CRITIC_EXTRA,
            amp_steps=ec.amp_obs_steps, amp_dim=O.AMP_DIM, num_actions=self.num_actions)
        self._alloc()
        if verbose:
            print(self.describe())
        self._reset_envs(torch.arange(self.num_envs, device=self.device))
        self.obs = self._observe(self._read(), torch.arange(self.num_envs, device=self.device))

    # ---------------------------------------------------------------------------- set-up
    def _setup_trajectories(self) -> None:
        tc = self.cfg.env.trajectory
        speed = 0.5 * (tc.speed_min + tc.speed_max)
        ids = sorted(self.scene.trajectories)
        fixed = [torch.as_tensor(time_polyline(self.scene.trajectories[k], speed, FIXED_TRAJ_DT),
                                 dtype=torch.float32, device=self.device) for k in ids]
        self.traj_len = max([tc.num_verts] + [f.shape[0] for f in fixed])
        self.fixed_traj = {k: pad_to(f, self.traj_len) for k, f in zip(ids, fixed)}
        # a procedural path ends early enough to be reached and held (60 steps) before the
        # episode's time limit, so that follow subtasks can complete like fixed ones
        margin = max(60, self.max_transition_steps) + 30
        self.rand_duration = max(self.max_episode_length - margin, self.max_episode_length // 2) * self.dt

    def _alloc(self) -> None:
        n, s, d = self.num_envs, self.num_subtasks, self.device
        z = lambda *shape, dtype=torch.long: torch.zeros(*shape, dtype=dtype, device=d)  # noqa: E731
        self.episode_length_buf = z(n)
        self.steps = z(n)
        """Control steps since the episode started (episode_length_buf may be randomised by a runner)."""
        self.subtask, self.hold = z(n), z(n)
        self.sub_done, self.sub_grasped = z(n, s, dtype=torch.bool), z(n, s, dtype=torch.bool)
        self.sub_start, self.sub_end = z(n, s) - 1, z(n, s) - 1
        self.sub_on_path, self.sub_path_steps = z(n, s), z(n, s)
        self.traj_verts = z(n, self.traj_len, 2, dtype=torch.float32)
        self.traj_dt = torch.full((n,), FIXED_TRAJ_DT, device=d)
        self.traj_t0 = z(n)
        self.grasp_obj = z(n) - 1
        self.actions = z(n, self.num_actions, dtype=torch.float32)
        ec = self.cfg.env
        self.h_self = O.History(n, ec.history_self, O.SELF_DIM, d)
        self.h_env = O.History(n, ec.history_env, O.env_dim(ec.height_map.grid), d)
        self.h_amp = O.History(n, ec.amp_obs_steps, O.AMP_DIM, d)

    def describe(self) -> str:
        """Start-up summary: scene, plan, observation groups and reward terms."""
        lines = [f"LHEnv '{self.cfg.task.name}': {self.num_envs} envs, character {self.character}, "
                 f"{len(self.scene.objects)} objects, dt {self.dt:.4f} s x {self.max_episode_length} steps, "
                 f"{self.backend.nthread} threads, device {self.device}",
                 "Plan: " + " -> ".join(f"{s.skill}({self.cfg.task.sample_target_from[s.index]})" for s in self.plan),
                 "Observation groups", "  group   shape"]
        sp = self.obs_spec
        shapes = {"self": f"{sp.self_steps} x {sp.self_dim}", "env": f"{sp.env_steps} x {sp.env_dim}",
                  "task": f"{sp.num_skills}", "critic": f"{sp.critic_dim}", "amp": f"{sp.amp_steps} x {sp.amp_dim}"}
        lines += [f"  {g:<7} {v}" for g, v in shapes.items()]
        lines.append(f"Actions: {self.num_actions}")
        return "\n".join(lines) + "\n" + self.rewards.table()

    # ---------------------------------------------------------------------------- VecEnv
    def get_observations(self) -> TensorDict:
        return self.obs

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        a = actions.to(self.device, torch.float32).clamp(-1.0, 1.0)
        self.actions = a
        if self.puppet:
            self._update_grasp(a)
        self.backend.step(self._ctrl(a), self.substeps)
        self.episode_length_buf += 1
        self.steps += 1
        st = self._read()
        tg = self._targets(st)
        ref = self._traj_ref(0.0)
        ref_vel = (self._traj_ref(self.dt) - ref) / self.dt
        dist = S.subtask_distance(tg["skill"], st.root_pos, tg["obj_pos"], tg["target"])
        rew, parts = self.rewards.compute(self._reward_ctx(st, tg, ref, ref_vel, dist))
        is_traj = tg["skill"] == S.TRAJ
        fell = st.root_pos[:, 2] < self.cfg.env.termination_height
        traj_fail = is_traj & ((st.root_pos[:, :2] - ref).norm(dim=-1) > self.cfg.env.traj_fail_distance)
        last_done = self._advance_plan(st, tg, dist, is_traj)
        iet = last_done if self.cfg.env.iet != "none" else torch.zeros_like(last_done)
        timeout = self.episode_length_buf >= self.max_episode_length
        terminated = fell | traj_fail
        time_outs = (timeout | iet) & ~terminated
        dones = terminated | time_outs
        extras: dict = {"time_outs": time_outs, "log": {f"Reward/{k}": v.mean() for k, v in parts.items()}}
        ids = dones.nonzero(as_tuple=False).squeeze(-1)
        if len(ids):
            prog = self.progress()
            prog.update(fell=fell, traj_failed=traj_fail, length=self.steps.clone())
            extras["episode_progress"] = prog
            extras["log"].update(self._episode_log(prog, ids))
            self._reset_envs(ids)
            st = self._read()
        same = not (self._advanced or len(ids))  # targets unchanged since the reward: reuse them
        self.obs = self._observe(st, ids, tg if same else None)
        return self.obs, rew, dones, extras

    # ---------------------------------------------------------------------------- control
    def _ctrl(self, a: torch.Tensor) -> torch.Tensor:
        q = pd_targets(a, self.dof_lo, self.dof_hi)
        if not self.puppet:
            return q
        yaw = self.backend.qpos[:, self.scene.root_qpos_adr + 3]
        return torch.cat((q, P.root_ctrl(a, yaw)), dim=-1)

    def _update_grasp(self, a: torch.Tensor) -> None:
        """Puppet grasp rule (`detach.envs.puppet`): weld on request when both hands are near."""
        want = a[:, P.NUM_ACTIONS - 1] > 0.0
        held = self.grasp_obj >= 0
        release = (held & ~want).nonzero(as_tuple=False).squeeze(-1)
        for k, eq in enumerate(self.ix.dyn_eq):
            r = release[self.grasp_obj[release] == k]
            self.backend.set_equality(r, eq, torch.zeros(len(r)))
        self.grasp_obj[release] = -1
        cand = (want & (self.grasp_obj < 0)).nonzero(as_tuple=False).squeeze(-1)
        if len(cand) == 0 or len(self.ix.dyn) == 0:
            return
        st = self._last_state
        dpos, dquat = st.obj_pos[cand][:, self.ix.dyn], st.obj_quat[cand][:, self.ix.dyn]
        hands = st.body_pos[cand][:, self.ix.hands]
        ok = P.grasp_condition(hands, dpos, dquat, self.ix.obj_half[self.ix.dyn])
        first = torch.where(ok.any(-1), ok.float().argmax(-1), torch.full_like(cand, -1))
        for k, eq in enumerate(self.ix.dyn_eq):
            sel = first == k
            if not bool(sel.any()):
                continue
            e = cand[sel]
            pq, pp = st.root_quat[e], st.root_pos[e]
            rel_p = quat_rotate(quat_conj(pq), dpos[sel, k] - pp)
            rel_q = quat_mul(quat_conj(pq), dquat[sel, k])
            data = torch.zeros(len(e), 12, device=self.device)
            data[:, 3:6], data[:, 6:10], data[:, 10] = rel_p, rel_q, 1.0
            self.backend.set_equality(e, eq, torch.ones(len(e)), data)
            self.grasp_obj[e] = k

    # ---------------------------------------------------------------------------- task
    def _read(self) -> SimState:
        self._last_state = read_state(self.backend, self.ix)
        return self._last_state

    def _targets(self, st: SimState) -> dict[str, torch.Tensor]:
        """Current subtask's skill, object pose and world target per env."""
        sub, pt = self.subtask, self.pt
        skill, obj = pt.skill[sub], pt.obj[sub]
        has_obj = obj >= 0
        n = self.num_envs
        if self.ix.obj_body.numel():
            oc = obj.clamp(min=0)
            ar = torch.arange(n, device=self.device)
            opos, oquat, olin = st.obj_pos[ar, oc], st.obj_quat[ar, oc], st.obj_lin[ar, oc]
            half = self.ix.obj_half[oc]
            sit = opos + quat_rotate(oquat, self.ix.tar_sit[oc])
            climb = opos + quat_rotate(oquat, self.ix.tar_climb[oc])
            climb[:, 2] += self.cfg.env.climb_pelvis_height
        else:
            opos = olin = sit = climb = torch.zeros(n, 3, device=self.device)
            oquat = torch.tensor([1.0, 0, 0, 0], device=self.device).expand(n, 4)
            half = torch.zeros(n, 3, device=self.device)
        target = torch.where((skill == S.SIT)[:, None], sit, climb)
        target = torch.where(pt.has_fixed[sub][:, None], pt.fixed_target[sub], target)
        is_traj = skill == S.TRAJ
        end = torch.cat((self.traj_verts[:, -1], torch.zeros(n, 1, device=self.device)), dim=-1)
        target = torch.where(is_traj[:, None], end, target)
        return dict(skill=skill, obj=obj, has_obj=has_obj, obj_pos=opos, obj_quat=oquat, obj_lin=olin,
                    obj_half=half, target=target, is_traj=is_traj)

    def _traj_ref(self, ahead: float | torch.Tensor) -> torch.Tensor:
        """Reference XY [N, 2] (or [N, k, 2] for a tensor of look-ahead times, s)."""
        t = (self.steps - self.traj_t0).float() * self.dt
        if isinstance(ahead, torch.Tensor):
            return sample_at(self.traj_verts, self.traj_dt, t[:, None] + ahead[None])
        return sample_at(self.traj_verts, self.traj_dt, t + ahead)

    def _reward_ctx(self, st: SimState, tg: dict, ref: torch.Tensor, ref_vel: torch.Tensor,
                    dist: torch.Tensor) -> RewardContext:
        dyn = self.ix.dyn
        rest = self.resets.rest_z_of(tg["obj"])
        return RewardContext(skill=tg["skill"], root_pos=st.root_pos, root_lin=st.body_lin[:, 0],
                             target=tg["target"], obj_pos=tg["obj_pos"], obj_rest_z=rest,
                             ref_xy=ref, ref_vel=ref_vel,
                             # the puppet's hinges are cosmetic (balance is not its problem): the
                             # power penalty, a humanoid regulariser, would only teach it to freeze
                             dist=dist, joint_power=st.joint_power * (0.0 if self.puppet else 1.0),
                             dyn_speed=st.obj_lin[:, dyn].norm(dim=-1) if len(dyn) else
                             torch.zeros(self.num_envs, 0, device=self.device))

    def _advance_plan(self, st: SimState, tg: dict, dist: torch.Tensor, is_traj: torch.Tensor) -> torch.Tensor:
        """Update hold counters, grasp and path statistics; fire transitions. Returns bool [N]:
        the last subtask completed at this step."""
        n, ar, sub = self.num_envs, torch.arange(self.num_envs, device=self.device), self.subtask
        if bool(is_traj.any()):
            on = distance_to_polyline(st.root_pos[:, :2], self.traj_verts) <= self.threshold
            self.sub_path_steps[ar, sub] += is_traj.long()
            self.sub_on_path[ar, sub] += (is_traj & on).long()
        carry = tg["skill"] == S.CARRY
        lifted = tg["obj_pos"][:, 2] >= self.resets.rest_z_of(tg["obj"]) + S.GRASP_LIFT
        self.sub_grasped[ar, sub] |= carry & lifted
        self.hold = S.update_hold(self.hold, dist, self.threshold)
        complete = self.hold >= self.max_transition_steps
        self.sub_done[ar, sub] |= complete
        self.sub_end[ar, sub] = torch.where(complete, self.steps, self.sub_end[ar, sub])
        last = sub == self.num_subtasks - 1
        adv = (complete & ~last).nonzero(as_tuple=False).squeeze(-1)
        self._advanced = len(adv) > 0
        if len(adv):
            self.subtask[adv] += 1
            self.hold[adv] = 0
            self._start_subtask(adv, st.root_pos[adv, :2])
        return complete & last

    def _start_subtask(self, ids: torch.Tensor, root_xy: torch.Tensor) -> None:
        """Stamp the start of each env's current subtask and load its trajectory."""
        sub = self.subtask[ids]
        self.sub_start[ids, sub] = self.steps[ids]
        self.traj_t0[ids] = self.steps[ids]
        tid = self.pt.traj_id[sub]
        rand = tid == RAND
        if bool(rand.any()):
            r = ids[rand]
            heading = (torch.rand(len(r), generator=self.gen) * 2 - 1).to(self.device) * math.pi
            verts, dt = random_trajectories(root_xy[rand], heading, self.cfg.env.trajectory,
                                            self.rand_duration, self.gen)
            self.traj_verts[r] = pad_to(verts, self.traj_len)
            self.traj_dt[r] = dt
        for k, verts in self.fixed_traj.items():
            sel = tid == k
            if bool(sel.any()):
                self.traj_verts[ids[sel]] = verts
                self.traj_dt[ids[sel]] = FIXED_TRAJ_DT
        other = tid == -2  # not a traj subtask: park the reference on the anchor (unused)
        if bool(other.any()):
            self.traj_verts[ids[other]] = root_xy[other][:, None, :].expand(-1, self.traj_len, -1)

    def _reset_envs(self, ids: torch.Tensor) -> None:
        qpos, qvel, root_xy = self.resets.sample(ids)
        self.backend.reset(ids, qpos, qvel)
        self.episode_length_buf[ids] = 0
        self.steps[ids] = 0
        self.subtask[ids] = 0
        self.hold[ids] = 0
        self.sub_done[ids] = False
        self.sub_grasped[ids] = False
        self.sub_start[ids] = -1
        self.sub_end[ids] = -1
        self.sub_on_path[ids] = 0
        self.sub_path_steps[ids] = 0
        self.grasp_obj[ids] = -1
        self._start_subtask(ids, root_xy)

    def set_reference_sampler(self, fn) -> None:
        """Reference-state initialisation source (`env.init` random/mixed), e.g. the motion
        library; see `detach.envs.resets` for the expected callable."""
        self.resets.reference_sampler = fn

    # ---------------------------------------------------------------------------- progress
    def progress(self) -> dict[str, torch.Tensor]:
        """Per-env plan progress (clones); see the module docstring."""
        scores = S.subtask_scores(self.pt.skill, self.sub_done, self.sub_grasped, self.sub_on_path,
                                  self.sub_path_steps, self.cfg.env.follow_on_path_frac)
        span = (self.sub_end - self.sub_start).float() * self.dt
        return dict(subtask=self.subtask.clone(), done=self.sub_done.clone(), score=scores,
                    grasped=self.sub_grasped.clone(), start=self.sub_start.clone(), end=self.sub_end.clone(),
                    exec_time=torch.where(self.sub_end >= 0, span, torch.full_like(span, float("nan"))),
                    on_path=self.sub_on_path.clone(), path_steps=self.sub_path_steps.clone(),
                    lh_success=S.lh_success(scores))

    def _episode_log(self, prog: dict, ids: torch.Tensor) -> dict[str, torch.Tensor]:
        log = {"Episode/length": prog["length"][ids].float(), "Success/lh": prog["lh_success"][ids].float(),
               "Episode/fall": prog["fell"][ids].float(), "Episode/traj_fail": prog["traj_failed"][ids].float()}
        for i, s in enumerate(self.plan):
            log[f"Success/{i}_{s.skill}"] = prog["score"][ids, i]
        return log

    # ---------------------------------------------------------------------------- observations
    def _observe(self, st: SimState, reset_ids: torch.Tensor, tg: dict | None = None) -> TensorDict:
        tg = tg if tg is not None else self._targets(st)
        R = heading_matrix(yaw_of(st.root_quat))
        ec = self.cfg.env
        samples = self._traj_ref(torch.arange(O.TRAJ_SAMPLES, device=self.device) * ec.trajectory.sample_dt)
        dyn = self.ix.dyn
        if ec.height_map.enabled:
            hmap = O.local_height_map(st.root_pos, R, self.hm_offsets, self.raster, st.obj_pos[:, dyn],
                                      st.obj_quat[:, dyn], self.ix.obj_half[dyn])
        else:
            hmap = torch.zeros(self.num_envs, self.hm_offsets.shape[0], device=self.device)
        f_self = O.self_frame(st.body_pos, st.body_quat, st.body_lin, st.body_ang, st.dof_pos, st.dof_vel, R)
        f_env = O.env_frame(st.root_pos, R, tg["target"], samples, tg["is_traj"], tg["has_obj"], tg["obj_pos"],
                            tg["obj_quat"], tg["obj_half"], hmap)
        f_amp = f_self[:, self.amp_idx]  # == O.amp_frame(...) of the same state (tested)
        for h, f in ((self.h_self, f_self), (self.h_env, f_env), (self.h_amp, f_amp)):
            h.push(f)
            if len(reset_ids):
                h.fill(reset_ids, f[reset_ids])
        task = torch.nn.functional.one_hot(tg["skill"], len(SKILLS)).float()
        extra = torch.cat(((tg["obj_lin"][:, None] @ R)[:, 0] * tg["has_obj"][:, None],
                           (self.hold.float() / self.max_transition_steps)[:, None],
                           (self.subtask.float() / self.num_subtasks)[:, None]), dim=-1)
        critic = torch.cat((f_self, f_env, task, extra), dim=-1)
        return TensorDict({"self": self.h_self.flat(), "env": self.h_env.flat(), "task": task,
                           "critic": critic, "amp": self.h_amp.flat()}, batch_size=[self.num_envs],
                          device=self.device)


def make_env(run_cfg: RunConfig, num_envs: int | None = None, device: str | torch.device = "cpu",
             eval_mode: bool = False, **kw) -> LHEnv:
    """The env of a resolved run configuration (`detach.config.resolve`)."""
    return LHEnv(run_cfg, num_envs=num_envs, device=device, eval_mode=eval_mode, **kw)
