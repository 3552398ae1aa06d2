"""What researchers from rsl-rl / IsaacLab expect of a run folder, through `detach-run` and
the files it writes: rsl-rl's metric names everywhere (log.mcap, TensorBoard, the progress
bar), TensorBoard and W&B (offline) through rsl-rl's own writers, the NaN guard, provenance.json,
params/agent.yaml loaded by stock rsl-rl code, and the export of every shipped model to ONNX
and TorchScript checked against eager torch."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from detach import cli
from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.models.factory import build_actor_critic
from detach.runfolder.names import AGENT_PARAMS_FILE, PROVENANCE_FILE
from detach.runfolder.folder import RunFolder, find_runs
from detach.runfolder.mcap_reader import read_metrics
from detach.runs.provenance import git_state
from detach.train.checkpoints import load_module_weights, read_checkpoint, write_checkpoint
from detach.train.run_config import complete_run_config
from detach.train.setup import default_action_std

ROOT = Path(__file__).resolve().parents[1]
FOLLOW = ROOT / "configs/tasks/follow.yaml"
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=6", "train.max_iterations=2", "eval.trials=2"]
PREFIXES = ("Loss/", "Train/", "Perf/", "Policy/", "Episode/", "Episode_Reward/", "Episode_Success/",
            "Episode_Termination/")
"""rsl-rl's names (and IsaacLab's for the environment's episode statistics): docs/METRICS.md."""
MODELS = sorted(p.stem for p in (ROOT / "configs/models").glob("*.yaml"))


def train_tiny(out: Path, *extra: str, model: str = "mlp") -> tuple[int, RunFolder]:
    code = cli.main([str(FOLLOW), "--model", model, "--out", str(out), "--no-eval", *TINY, *extra])
    runs = find_runs(out)
    assert len(runs) == 1
    return code, runs[0]


def test_tensorboard_mcap_and_progress_bar_share_rsl_rl_names_and_the_run_records_its_provenance(
        tmp_path: Path) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    code, run = train_tiny(tmp_path / "runs", "train.logger=tensorboard")
    assert code == 0 and run.status().state == "finished"
    metrics = read_metrics(run.log_path)
    keys = {k for m in metrics for k in m if k not in ("iteration", "stage")}
    assert keys and all(k.startswith(PREFIXES) for k in keys), sorted(k for k in keys if not k.startswith(PREFIXES))
    for key in ("Loss/surrogate", "Loss/value", "Loss/entropy", "Loss/learning_rate", "Perf/total_fps",
                "Train/mean_reward", "Train/mean_episode_length", "Policy/mean_std", "Episode_Success/lh"):
        assert key in keys, key
    events = list(run.path.glob("events.out.tfevents.*"))
    assert events, "no TensorBoard event file in the run folder"
    assert not (run.path / "git").exists(), "provenance.json holds the code state, not rsl-rl's git/ folder"
    acc = EventAccumulator(str(run.path))
    acc.Reload()
    assert set(acc.Tags()["scalars"]) == keys, "TensorBoard and log.mcap carry the same names"
    surrogate = [e.value for e in acc.Scalars("Loss/surrogate")]
    assert np.allclose(surrogate, [m["Loss/surrogate"] for m in metrics], rtol=1e-5)
    # the progress bar shows the success fractions (stderr is in stdout.log)
    assert re.search(r"success_lh=\d\.\d\d", run.stdout_path.read_text())
    # provenance.json: commit, diff, python, packages, device, command line
    record = json.loads((run.path / PROVENANCE_FILE).read_text())["runs"][0]
    assert record["packages"]["torch"] == torch.__version__ and record["python"].count(".") == 2
    assert record["device"]["device"] == "cpu" and record["command"] and record["resumed"] is False
    if record["git"] is not None:  # a source checkout (CI clones one)
        assert re.fullmatch(r"[0-9a-f]{40}", record["git"]["commit"]) and "diff" in record["git"]
    # a resume adds a record
    assert cli.main(["--resume", str(run.path), "train.max_iterations=3", "--no-eval"]) == 0
    records = json.loads((run.path / PROVENANCE_FILE).read_text())["runs"]
    assert [r["resumed"] for r in records] == [False, True]


def test_stock_rsl_rl_loads_a_checkpoint_through_params_agent_yaml(tmp_path: Path) -> None:
    from rsl_rl.runners import OnPolicyRunner

    from detach.train.amp_ppo import AmpPPO

    code, run = train_tiny(tmp_path / "runs")
    assert code == 0
    assert not list(run.path.glob("events.out.tfevents.*")), "train.logger defaults to none"
    train_cfg = yaml.safe_load((run.path / AGENT_PARAMS_FILE).read_text())
    assert train_cfg["algorithm"]["class_name"] == "detach.train.amp_ppo:AmpPPO"
    cfg = run.config()
    env = make_env(cfg, num_envs=4)
    runner = OnPolicyRunner(env, train_cfg, log_dir=None, device="cpu")  # stock rsl-rl
    assert isinstance(runner.alg, AmpPPO)
    checkpoint = run.latest_checkpoint()
    runner.load(str(checkpoint))
    policy = runner.get_inference_policy()
    ours, _critic = build_actor_critic(cfg.model, env.obs_spec, env.get_observations(), num_actions=env.num_actions,
                                       default_std=default_action_std(cfg))
    load_module_weights(ours, read_checkpoint(checkpoint)["actor_state_dict"], checkpoint, "actor")
    ours.eval()
    obs = env.get_observations()
    with torch.no_grad():
        torch.testing.assert_close(policy(obs), ours(obs))


def test_a_run_that_goes_nan_fails_and_says_where(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, run = train_tiny(tmp_path / "runs", "rewards.terms.follow/position=.nan")
    status = run.status()
    assert code == 1 and status.state == "failed"
    assert "NonFiniteError" in status.error and "rewards at iteration 0, step 0" in status.error
    assert "envs 0, 1, 2, 3" in status.error
    assert "run failed" in capsys.readouterr().err
    assert not run.checkpoint_files(), "no checkpoint of NaN weights"


def test_wandb_writes_an_offline_run_into_the_run_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.delenv("WANDB_DIR", raising=False)
    monkeypatch.setenv("WANDB_SILENT", "true")
    code, run = train_tiny(tmp_path / "runs", "train.logger=wandb", "train.wandb_project=detach-test")
    assert code == 0 and run.status().state == "finished"
    offline = list((run.path / "wandb").glob("offline-run-*"))
    assert len(offline) == 1 and list(offline[0].glob("*.wandb")), "W&B's offline run file"
    assert list(run.path.glob("events.out.tfevents.*")), "rsl-rl's W&B writer also writes TensorBoard"


def _run_with_checkpoint(out: Path, model: str) -> tuple[RunFolder, torch.nn.Module, object]:
    """A run folder of `model` holding checkpoint 3 of an actor whose normaliser has
    non-trivial statistics (no training needed to check an export)."""
    cfg = resolve(FOLLOW, model, TINY + (["train.init_from=" + str(out / "base.pt")]
                                         if model in ("cml_incremental", "tokenhsi_adapt") else []))
    if cfg.train.init_from:
        write_checkpoint(out / "base.pt", {"iter": 0})  # only its existence is checked here
    cfg = complete_run_config(cfg)
    run = RunFolder.create(out, cfg)
    env = make_env(cfg, num_envs=4)
    torch.manual_seed(0)
    actor, critic = build_actor_critic(cfg.model, env.obs_spec, env.get_observations(), num_actions=env.num_actions,
                                       default_std=default_action_std(cfg))
    with torch.no_grad():
        for name, buf in actor.named_buffers():
            if "normalizer" in name and buf.is_floating_point() and buf.dim() > 0:
                buf.copy_(torch.rand_like(buf) + 0.5)  # mean and std away from 0 and 1
    write_checkpoint(run.checkpoints / "model_3.pt", {
        "actor_state_dict": actor.state_dict(), "critic_state_dict": critic.state_dict(), "iter": 3,
        "infos": {"model": cfg.model_name, "model_kind": cfg.model.kind}})
    actor.eval()
    return run, actor, env


@pytest.mark.parametrize("model", MODELS)
def test_every_shipped_model_exports_to_onnx_and_torchscript_as_torch_computes_it(tmp_path: Path,
                                                                                  model: str) -> None:
    onnxruntime = pytest.importorskip("onnxruntime")
    from detach.runs.export import TOLERANCE, export_run

    run, actor, env = _run_with_checkpoint(tmp_path, model)
    obs = env.get_observations()
    obs = {g: obs[g] * (1.0 if g == "task" else 2.0) + (0.0 if g == "task" else 0.1) for g in actor.obs_groups}
    flat = torch.cat([obs[g] for g in actor.obs_groups], dim=-1)
    with torch.no_grad():
        eager = actor(obs).numpy()
    onnx = export_run(run.path, 3, "onnx")
    assert onnx.path == run.path / "exported/policy_3.onnx" and onnx.max_abs_diff <= TOLERANCE
    session = onnxruntime.InferenceSession(str(onnx.path), providers=["CPUExecutionProvider"])
    got = session.run(["actions"], {"obs": flat.numpy()})[0]
    assert got.shape == eager.shape and np.abs(got - eager).max() <= TOLERANCE, np.abs(got - eager).max()
    jit = export_run(run.path, None, "jit")
    assert jit.path.name == "policy_3.pt"
    loaded = torch.jit.load(str(jit.path))
    assert np.abs(loaded(flat).detach().numpy() - eager).max() <= TOLERANCE
    layout = json.loads(onnx.layout.read_text())
    groups = layout["input"]["groups"]
    assert [g["name"] for g in groups] == ["self", "env", "task"]
    assert sum(g["width"] for g in groups) == layout["input"]["width"] == flat.shape[1]
    assert groups[0]["history"] == {"steps": env.obs_spec.self_steps, "frame": env.obs_spec.self_dim,
                                    "order": "time-major, oldest frame first"}
    assert layout["output"]["width"] == env.num_actions and layout["kind"] == run.config().model.kind


def test_export_through_the_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("onnxruntime")
    run, _actor, _env = _run_with_checkpoint(tmp_path, "mlp")
    target = tmp_path / "policy.pt"
    assert cli.main(["export", str(run.path), "--format", "jit", "--output", str(target)]) == 0
    assert target.exists() and target.with_suffix(".json").exists()
    assert "exported to" in capsys.readouterr().out
    assert cli.main(["export", str(run.path), "--checkpoint", "9"]) == 2
    assert "no model_9.pt (the run has 3)" in capsys.readouterr().err


def test_a_symlinked_assets_or_runs_folder_does_not_make_the_provenance_dirty(tmp_path: Path) -> None:
    """A work tree whose assets/ and runs/ are symlinks (a second checkout sharing the built
    assets) is as clean as one holding them: the .gitignore patterns match links too."""
    if shutil.which("git") is None:
        pytest.skip("git is not installed")
    repo = tmp_path / "checkout"
    repo.mkdir()
    (repo / ".gitignore").write_text((ROOT / ".gitignore").read_text())
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(repo)]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", ".gitignore"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "init"], check=True)
    for name in ("assets", "runs"):
        (tmp_path / name).mkdir()
        (repo / name).symlink_to(tmp_path / name)
    state = git_state(repo)
    assert state is not None and state["untracked"] == [] and state["dirty"] is False
