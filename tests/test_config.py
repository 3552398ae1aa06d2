"""The strict config loader, through its public API and the `detach-run` CLI."""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest

from detach import cli
from detach.config import ConfigError, ConfigOrigin, dump, load_run_config, load_task, resolve
from detach.config.keys import all_keys
from detach.config.ranges import AT_LEAST_1, check_ranges, ranged

ROOT = Path(__file__).resolve().parents[1]
TASKS = sorted((ROOT / "configs" / "tasks").glob("*.yaml"))
MODELS = sorted(p.stem for p in (ROOT / "configs" / "models").glob("*.yaml"))


def test_every_task_and_model_is_shipped() -> None:
    assert {p.stem for p in TASKS} == {"follow", "carry", "climb", "sit", "lh1", "lh2", "lh3"}
    assert set(MODELS) == {"detach", "ablation_a1", "ablation_a2", "tokenhsi", "cml", "mlp",
                           "tokenhsi_adapt", "cml_incremental"}


@pytest.mark.parametrize("task", TASKS, ids=lambda p: p.stem)
@pytest.mark.parametrize("model", MODELS)
def test_shipped_configs_resolve_and_round_trip(task: Path, model: str, tmp_path: Path) -> None:
    cfg = resolve(task, model, seed=3)
    assert cfg.task_name == task.stem and cfg.model_name == model and cfg.seed == 3
    dumped = tmp_path / "config.yaml"
    dumped.write_text(dump(cfg))
    assert load_run_config(dumped) == cfg
    assert dump(load_run_config(dumped)) == dump(cfg)


def test_lh1_numbers_from_the_paper() -> None:
    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "detach")
    t = cfg.task
    box, chair, platform, wall_s, wall_n = t.scene
    assert box.pos3d == (4.5, -4.0, 0.35) and not box.static
    assert chair.pos3d == (0.0, 0.0, 1.46) and chair.z_rot_angle == -1.57
    assert platform.pos3d == (0.0, 0.0, 0.5) and platform.size == (5.0, 3.0, 1.0)
    assert {wall_s.pos3d, wall_n.pos3d} == {(6.0, -3.25, 1.5), (6.0, 3.25, 1.5)}
    assert wall_s.size == (0.3, 5.0, 3.0)
    assert t.trajectories[0] == ((10, 4), (10, 2), (7, 0), (5, 0), (4, -1))
    assert t.target_positions == ((0.0, -1.8, 0.35),)
    assert t.humanoid.init_pos2d == (10.0, 4.0)
    assert t.plan == ("follow", "carry", "climb", "sit")
    assert t.target_object == (0, 0, 0, 1)
    assert t.sample_target_from == ("traj_0", "tarpos_0", "scene_0", "scene_1")
    e, r = cfg.env, cfg.rewards
    assert (e.episode_length, e.success_threshold, e.max_transition_steps) == (1200, 0.3, 60)
    assert cfg.eval.max_transition_steps == 20
    assert (e.termination_height, e.traj_fail_distance, e.amp_obs_steps) == (0.15, 4.0, 10)
    assert (e.mixed_init_prob, e.height_map.grid, e.height_map.spacing) == (0.5, 25, 0.1)
    g = e.trajectory
    assert (g.num_samples, g.sample_dt, g.speed_min, g.speed_max) == (10, 0.5, 1.4, 1.5)
    assert (g.accel_max, g.sharp_turn_prob, g.sharp_turn_angle) == (2.0, 0.02, 1.57)
    assert (r.power_coeff, r.dyn_obj_speed_penalty_coeff, r.dyn_obj_speed_threshold) == (
        0.0005, 1.0, 1.5)
    assert round(1 / (cfg.sim.physics_dt * cfg.sim.substeps)) == 30


def test_lh2_lh3_plans_from_the_paper() -> None:
    lh2, lh3 = (load_task(ROOT / f"configs/tasks/{n}.yaml") for n in ("lh2", "lh3"))
    assert lh2.plan == ("follow", "carry", "follow", "sit")
    assert lh2.scene[8].category == "sofa" and lh2.scene[8].pos3d == (18.0, 17.0, 0.35)
    assert lh2.trajectories[0][0] == (11.5, 0.0) and lh2.trajectories[0][-1] == (11.5, 8.0)
    assert lh2.trajectories[1][0] == (14.0, 11.0) and lh2.trajectories[1][-1] == (18.0, 14.4)
    assert lh3.plan == ("follow", "carry", "follow", "climb", "sit")
    assert lh3.target_object == (0, 0, 0, 1, 2)
    assert lh3.sample_target_from == ("traj_0", "tarpos_0", "traj_1", "scene_1", "scene_2")
    assert len(lh3.scene) == 11 and lh3.scene[1].pos3d == (15.0, 18.2, 0.43)
    assert len(lh3.trajectories[1]) == 12
    assert lh3.trajectories[1][0] == (14.0, 11.0) and lh3.trajectories[1][-1] == (15.0, 16.0)


def test_ablations_change_only_their_switch() -> None:
    task = ROOT / "configs/tasks/lh3.yaml"
    full = resolve(task, "detach").model
    a1, a2 = resolve(task, "ablation_a1").model, resolve(task, "ablation_a2").model
    assert a1 == type(full)(**{**full.__dict__, "use_env_encoder": False})
    assert a2 == type(full)(**{**full.__dict__, "use_self_encoder": False})


def test_overrides_set_add_and_index() -> None:
    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "detach", [
        "env.character=puppet", "sim.num_envs=4", "scene[0].pos3d=[1, 2, 0.35]",
        "scene.1.z_rot_angle=0.5", "+rewards.terms.follow/bonus=0.25",
        "train.amp.disc_hidden=[64, 32]", "model.use_env_encoder=false",
        "model.self_encoder.predictor_hidden=32"])
    assert cfg.env.character == "puppet" and cfg.sim.num_envs == 4
    assert cfg.task.scene[0].pos3d == (1.0, 2.0, 0.35) and cfg.task.scene[1].z_rot_angle == 0.5
    assert cfg.rewards.terms["follow/bonus"] == 0.25
    assert cfg.train.amp.disc_hidden == (64, 32) and cfg.model.use_env_encoder is False
    assert cfg.model.self_encoder.predictor_hidden == 32  # a key of the kind's own config class


def test_exponent_numbers_without_a_dot_are_numbers() -> None:
    """`train.learning_rate=1e-5` was refused as "expected a number, found str '1e-5'" (YAML 1.1
    reads an exponent without a dot as a string); a word is still refused."""
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", ["train.learning_rate=1e-5", "sim.physics_dt=5E-3"])
    assert cfg.train.learning_rate == 1e-5 and cfg.sim.physics_dt == 5e-3
    with pytest.raises(ConfigError, match="expected a number, found str 'e5'"):
        resolve(ROOT / "configs/tasks/follow.yaml", "mlp", ["train.learning_rate=e5"])


def test_dry_run_prints_config_and_folder(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main([str(ROOT / "configs/tasks/lh3.yaml"), "--model", "ablation_a1",
                     "--dry-run", "--seed", "7", "sim.num_envs=8"])
    out = capsys.readouterr().out
    assert code == 0
    assert "use_env_encoder: false" in out and "num_envs: 8" in out
    folder = out.strip().splitlines()[-1]
    assert folder.startswith("# run folder: runs/") and folder.endswith("-lh3-ablation_a1-s7")


def test_help_documents_every_flag(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for flag in ("--model", "--seed", "--device", "--out", "--dry-run", "key=value"):
        assert flag in out


GOOD_TASK = """\
name: t
scene:
  - {name: box, category: Box, model_id: b, static: false, pos3d: [1, 0, 0.35]}
  - {name: chair, category: chair, model_id: c, pos3d: [3, 0, 0.46]}
trajectories:
  0: [[0, 0], [1, 1]]
target_positions: [[2, 2, 0.35]]
plan: [traj, carry, sit]
target_object: [0, 0, 1]
sample_target_from: [traj_0, tarpos_0, scene_1]
"""

# (name, {file: text}, extra CLI overrides, expected fragment of the one-line error)
BROKEN: list[tuple[str, dict[str, str], list[str], str]] = [
    ("typo_key", {"t.yaml": GOOD_TASK + "env: {episode_lenght: 10}\n"}, [],
     "t.yaml:11: env.episode_lenght: unknown key (did you mean 'episode_length'?)"),
    ("wrong_type", {"t.yaml": GOOD_TASK + "env: {episode_length: long}\n"}, [],
     "env.episode_length: expected an integer, found str 'long'"),
    ("bool_for_number", {"t.yaml": GOOD_TASK + "sim: {physics_dt: true}\n"}, [],
     "sim.physics_dt: expected a number, found bool True"),
    ("wrong_length", {"t.yaml": GOOD_TASK.replace("[3, 0, 0.46]", "[3, 0]")}, [],
     "t.yaml:4: scene[1].pos3d: expected a list of 3 values, found 2"),
    ("plan_length", {"t.yaml": GOOD_TASK.replace("target_object: [0, 0, 1]",
                                                 "target_object: [0, 1]")}, [],
     "target_object: expected 3 entries (one per plan step"),
    ("bad_scene_index", {"t.yaml": GOOD_TASK.replace("scene_1]", "scene_7]")}, [],
     "sample_target_from[2]: 'scene_7' names a missing scene entry (have 2 entries)"),
    ("bad_traj_index", {"t.yaml": GOOD_TASK.replace("[traj_0,", "[traj_3,")}, [],
     "'traj_3' names a missing trajectories entry (have [0])"),
    ("bad_tarpos_index", {"t.yaml": GOOD_TASK.replace("tarpos_0", "tarpos_1")}, [],
     "'tarpos_1' names a missing target_positions entry"),
    ("bad_source_word", {"t.yaml": GOOD_TASK.replace("tarpos_0", "target_0")}, [],
     "expected traj_K, tarpos_K or scene_K, found 'target_0'"),
    ("bad_skill", {"t.yaml": GOOD_TASK.replace("[traj, carry, sit]", "[traj, carry, sitt]")},
     [], "t.yaml:8: plan[2]: unknown skill 'sitt' (did you mean 'sit'?); available: follow, carry, "
         "climb, sit"),
    ("skill_source", {"t.yaml": GOOD_TASK.replace("scene_1]", "traj_0]")},
     [], "t.yaml:10: sample_target_from[2]: 'sit' takes its target from scene_K, tarpos_K, found traj_0"),
    ("bad_object_index", {"t.yaml": GOOD_TASK.replace("[0, 0, 1]", "[0, 0, 5]")}, [],
     "target_object[2]: object index 5 for 'sit' does not exist (scene has 2 objects)"),
    ("carry_static", {"t.yaml": GOOD_TASK.replace("[0, 0, 1]\n", "[0, 1, 1]\n")}, [],
     "'carry' needs a dynamic object, but scene[1] (chair) is static"),
    ("missing_required", {"t.yaml": GOOD_TASK.replace("model_id: c, ", "")}, [],
     "scene[1]: missing required key 'model_id' (SceneObjectCfg)"),
    ("bad_literal", {"t.yaml": GOOD_TASK + "env: {iet: sometimes}\n"}, [],
     "env.iet: expected one of 'none', 'last_subtask', 'all', found str 'sometimes'"),
    ("bad_character", {"t.yaml": GOOD_TASK + "env: {character: robot}\n"}, [],
     "t.yaml:11: env.character: unknown character 'robot'; available: humanoid, puppet"),
    ("bad_backend", {"t.yaml": GOOD_TASK}, ["sim.backend=gpu"],
     "<command line>: sim.backend: unknown physics backend 'gpu'; available: mujoco_batch"),
    ("bad_reward_term", {"t.yaml": GOOD_TASK}, ["+rewards.terms.sit/sea=1"],
     "rewards.terms: unknown term 'sit/sea'"),
    ("bad_model_kind", {"t.yaml": GOOD_TASK}, ["model.kind=transformer"],
     "model.kind: unknown model kind 'transformer'; available: cml, detach, mlp, tokenhsi"),
    ("unknown_top_key", {"t.yaml": GOOD_TASK + "scenes: []\n"}, [],
     "scenes: unknown key (did you mean 'scene'?)"),
    ("model_in_task", {"t.yaml": GOOD_TASK + "model: {kind: mlp}\n"}, [],
     "model: 'model' belongs in a model config"),
    ("duplicate_key", {"t.yaml": GOOD_TASK + "plan: [traj]\n"}, [], "duplicate key 'plan'"),
    ("missing_extends", {"t.yaml": "extends: nowhere.yaml\n" + GOOD_TASK}, [],
     "t.yaml:1: extends: extends a file that does not exist"),
    ("cyclic_extends", {"t.yaml": "extends: a.yaml\n" + GOOD_TASK,
                        "a.yaml": "extends: b.yaml\n", "b.yaml": "extends: a.yaml\n"}, [],
     "cyclic extends:"),
    ("not_yaml", {"t.yaml": "plan: [traj\nscene: {\n"}, [], "t.yaml:2: not valid YAML"),
    ("empty_file", {"t.yaml": ""}, [], "t.yaml: file is empty"),
    ("top_level_list", {"t.yaml": "- a\n- b\n"}, [],
     "expected a mapping of config keys at the top level, found list"),
    ("short_trajectory", {"t.yaml": GOOD_TASK.replace("[[0, 0], [1, 1]]", "[[0, 0]]")}, [],
     "trajectories[0]: expected at least 2 waypoints, found 1"),
    ("random_scene_source", {"t.yaml": GOOD_TASK.replace("scene_1]", "scene_rand]")}, [],
     "only traj_rand may be random, found 'scene_rand'"),
    ("override_unknown", {"t.yaml": GOOD_TASK}, ["env.charcter=puppet"],
     "<command line>: env.charcter: override of unknown key (did you mean 'character'?)"),
    ("override_bad_value", {"t.yaml": GOOD_TASK}, ["sim.num_envs=[1, 2]"],
     "sim.num_envs: expected an integer, found list [1, 2]"),
    ("override_bad_index", {"t.yaml": GOOD_TASK}, ["scene[5].pos3d=[0, 0, 0]"],
     "no item 5 (the list has 2 items)"),
    ("history_frames_negative", {"t.yaml": GOOD_TASK}, ["model.history_frames=-1"],
     "model.history_frames: expected >= 0 (0 = every frame), found -1"),
    ("history_frames_not_mlp", {"t.yaml": GOOD_TASK}, ["model.kind=detach"],
     "model.history_frames: unknown key; valid keys: kind, adapter_units"),
    ("negative_history_frames", {"t.yaml": GOOD_TASK}, ["model.history_frames=-1"],
     "model.history_frames: expected >= 0 (0 = every frame), found -1"),
    ("shared_trunk_mlp", {"t.yaml": GOOD_TASK}, ["model.shared_trunk=true"],
     "model.shared_trunk: override of unknown key (use +model.shared_trunk=... to add a new key)"),
    ("negative_subtask_bonus", {"t.yaml": GOOD_TASK}, ["rewards.subtask_bonus=-1"],
     "<command line>: rewards.subtask_bonus: expected a value >= 0, found -1.0"),
    ("override_no_equals", {"t.yaml": GOOD_TASK}, ["sim.num_envs"],
     "bad override 'sim.num_envs': expected key.path=value"),
    ("missing_task_file", {}, [], "t.yaml: task file not found"),
]


@pytest.mark.parametrize("name,files,overrides,expected", BROKEN, ids=[b[0] for b in BROKEN])
def test_broken_config_gives_one_line_error_and_exit_2(
        name: str, files: dict[str, str], overrides: list[str], expected: str,
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for fname, text in files.items():
        (tmp_path / fname).write_text(textwrap.dedent(text))
    code = cli.main(["train", str(tmp_path / "t.yaml"), "--model", "mlp", "--dry-run", *overrides])
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("detach-run: error: ")
    assert expected in lines[0], lines[0]


def test_unknown_model_suggests_closest(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main([str(ROOT / "configs/tasks/lh1.yaml"), "--model", "tokenhs", "--dry-run"])
    assert code == 2
    assert "unknown model 'tokenhs' (did you mean 'tokenhsi'?)" in capsys.readouterr().err


def test_action_std_defaults_to_the_characters_and_an_override_wins() -> None:
    from detach.train.run_config import resolve_run

    follow = ROOT / "configs/tasks/follow.yaml"
    assert resolve(follow, "detach").model.init_noise_std is None  # null: the character's
    assert resolve_run(follow, "detach").model.init_noise_std == 0.1
    assert resolve_run(follow, "mlp", ["env.character=puppet"]).model.init_noise_std == 1.0
    assert resolve_run(follow, "mlp", ["env.character=puppet", "model.init_noise_std=0.3"]).model.init_noise_std == 0.3
    dumped = dump(resolve_run(follow, "tokenhsi"))
    assert "init_noise_std: 0.1" in dumped  # config.yaml has the number


def test_model_config_is_typed_by_kind_and_old_run_configs_still_load(tmp_path: Path) -> None:
    from detach.models.detach_net import DetachCfg
    from detach.models.mlp import MLPCfg

    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "detach")
    assert type(cfg.model) is DetachCfg and cfg.model.shared_trunk is True
    assert type(resolve(ROOT / "configs/tasks/follow.yaml", "mlp").model) is MLPCfg
    # A config.yaml written before the model section was split (one class with every field,
    # and rewards.decoupling_mask_strength) loads as the run's kind.
    text = dump(cfg).replace("  kind: detach\n", "  kind: detach\n  history_frames: 0\n  gru_hidden: 256\n")
    text = text.replace("  terms:", "  decoupling_mask_strength: 0.3\n  terms:", 1)
    (tmp_path / "config.yaml").write_text(text)
    assert load_run_config(tmp_path / "config.yaml") == cfg


def test_model_yaml_by_path_and_unknown_section(tmp_path: Path) -> None:
    model = tmp_path / "tiny.yaml"
    model.write_text("model: {kind: mlp, adapter_units: [32]}\ntrain: {max_iterations: 3}\n")
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", str(model))
    assert cfg.model_name == "tiny" and cfg.model.adapter_units == (32,)
    model.write_text("model: {kind: mlp}\nenv: {episode_length: 3}\n")
    with pytest.raises(ConfigError, match=r"tiny.yaml:2: env: unknown key"):
        resolve(ROOT / "configs/tasks/follow.yaml", str(model))


def test_cuda_request_on_a_cpu_machine_is_a_user_error(
        capsys: pytest.CaptureFixture[str]) -> None:
    import torch

    code = cli.main([str(ROOT / "configs/tasks/follow.yaml"), "--device", "cuda", "--dry-run"])
    if torch.cuda.is_available():
        assert code == 0
    else:
        assert code == 2 and "CUDA is not available" in capsys.readouterr().err


def test_values_out_of_range_name_their_file_and_line(tmp_path: Path) -> None:
    model = tmp_path / "tiny.yaml"
    model.write_text(textwrap.dedent("""\
        extends: {models}/mlp.yaml
        train:
          max_iterations: 0
        """).format(models=ROOT / "configs" / "models"))
    with pytest.raises(ConfigError, match=r"tiny.yaml:3: train.max_iterations: expected a value >= 1, found 0"):
        resolve(ROOT / "configs/tasks/follow.yaml", str(model))
    with pytest.raises(ConfigError, match=r"<command line>: seed: expected a value in \[0, 4294967295\], found -1"):
        resolve(ROOT / "configs/tasks/follow.yaml", "mlp", seed=-1)



@dataclass(frozen=True)
class _Inner:
    n: int = ranged(1, AT_LEAST_1)


@dataclass(frozen=True)
class _Outer:
    inner: _Inner = _Inner()
    items: tuple[_Inner, ...] = ()


def test_a_range_is_declared_on_its_field() -> None:
    """Ranges are field metadata (`ranged`, no table of key paths): the check walks every
    section, nested and listed ones too, and `detach-run keys` shows each range with its key."""
    check_ranges(_Outer(items=(_Inner(), _Inner(2))), ConfigOrigin())
    with pytest.raises(ConfigError, match=r"^<command line>: inner.n: expected a value >= 1, found 0$"):
        check_ranges(_Outer(inner=_Inner(0)), ConfigOrigin())
    with pytest.raises(ConfigError, match=r"^<command line>: items\[1\].n: expected a value >= 1, found -3$"):
        check_ranges(_Outer(items=(_Inner(), _Inner(-3))), ConfigOrigin())
    docs = {k.path: k.doc for k in all_keys()}
    assert docs["sim.num_envs"].endswith("(range: in [1, 1048576])")
    assert docs["train.amp.learning_rate"].endswith("(range: > 0)")
    assert docs["eval.confidence"].endswith("(range: in (0, 1))")

def test_checkpoint_retention_has_a_stated_default() -> None:
    keep = resolve(ROOT / "configs/tasks/follow.yaml", "mlp").train.keep_checkpoints
    assert (keep.last, keep.every) == (3, 500)
    keep = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", ["train.keep_checkpoints.last=0"]).train.keep_checkpoints
    assert keep.last == 0
