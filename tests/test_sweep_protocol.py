"""Sweeps as graphs of runs that build on runs (the paper's progressive protocol), their locks,
and `train.init_from`, through the `detach-run` CLI on tiny puppet runs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import torch

from detach import cli
from detach.config import resolve
from detach.runs.curves import run_curve
from detach.runfolder.folder import find_runs
from detach.runs.sweep import _lock_path, file_lock
from detach.runs.sweep_config import load_sweep
from detach.runs.sweep_graph import cells

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "train.max_iterations=2"]


def write_sweep(tmp_path: Path, models: str = "[mlp]", extra: str = "") -> Path:
    sweep = tmp_path / "sweeps" / "mini.yaml"
    sweep.parent.mkdir(parents=True, exist_ok=True)
    sweep.write_text(textwrap.dedent(f"""\
        extends: {ROOT / 'configs/sweeps/base/protocol.yaml'}
        name: mini
        models: {models}
        seeds: [0]
        table: skills
        stages:
          - {{name: follow, task: {ROOT / 'configs/tasks/follow.yaml'}}}
          - {{name: carry, task: {ROOT / 'configs/tasks/carry.yaml'}, init_from: follow}}
          - name: lh1
            task: {ROOT / 'configs/tasks/lh1.yaml'}
            init_from: carry
            zero_shot: {{overrides: ["rewards.paid_skills=[follow, carry]"]}}
        eval:
          follow: [{ROOT / 'configs/tasks/follow.yaml'}]
          carry: []
          lh1: [{ROOT / 'configs/tasks/lh1.yaml'}, {ROOT / 'configs/tasks/lh2.yaml'}]
        presets:
          tiny: {{eval_trials: 2, overrides: [{', '.join(TINY)}]}}
        """) + extra)
    return sweep


def test_a_sweep_runs_its_stages_in_order_each_starting_from_the_last(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    sweep = write_sweep(tmp_path)
    out = tmp_path / "runs"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--out", str(out)]) == 0
    runs = {r.status().cell.split("/")[0]: r for r in find_runs(out)}
    assert sorted(runs) == ["carry", "follow", "lh1"] and all(r.status().state == "finished" for r in runs.values())
    carry, lh1 = runs["carry"].config(), runs["lh1"].config()
    assert carry.train.init_from == str(runs["follow"].path.resolve())
    assert lh1.train.init_from == str(runs["carry"].path.resolve())
    assert lh1.rewards.paid_skills == ("follow", "carry")  # zero-shot: climb and sit never paid
    assert "initialised from" in runs["lh1"].stdout_path.read_text()
    # the protocol's test_seed_offset: a sweep's cells play the held-out test trials only
    assert (runs["follow"].path / "eval.test.json").exists() and not list(runs["carry"].path.glob("eval*.json"))
    assert sorted(p.name for p in runs["lh1"].path.glob("eval*.json")) == ["eval.test.json", "eval_lh2.test.json"]
    printed = capsys.readouterr().out
    assert "[3/3]" in printed and "done" in printed
    # a second run of the sweep has nothing to do; a table of it has both LH columns
    stamps = {r.path: r.status_path.stat().st_mtime for r in find_runs(out)}
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--out", str(out)]) == 0
    assert {r.path: r.status_path.stat().st_mtime for r in find_runs(out)} == stamps
    assert cli.main(["table", str(sweep), "--runs", str(out)]) == 2, "the default cells were never run"
    assert "no evaluation on the test trials found" in capsys.readouterr().err
    assert cli.main(["table", str(sweep), "--runs", str(out), "--preset", "tiny"]) == 0
    table = (out / "tables" / "mini.md").read_text()
    assert "LH1 (mean)" in table and "LH1 (chain)" in table and "| MLP |" in table
    # learning curves beside the table, one figure per stage, from the runs' logs
    for stage, run in runs.items():  # a stage whose 2 iterations ended no episode has nothing to draw
        curve = run_curve(run, "mlp", 0)
        png = out / "tables" / f"curves_mini_{stage}.png"  # named by sweep and stage
        assert png.exists() == (curve is not None), stage
        if curve is not None:
            assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
            assert curve.label == "mlp s0" and curve.iterations == [0, 1]
            assert all(len(v) == 2 for v in curve.values.values())
    # an evaluation the sweep asks for that a finished cell lacks is run, without training again
    lh1 = runs["lh1"]
    (lh1.path / "eval_lh2.test.json").unlink()
    trained = lh1.stdout_path.read_text().count("stage: ")
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--out", str(out)]) == 0
    assert (lh1.path / "eval_lh2.test.json").exists()
    assert lh1.stdout_path.read_text().count("stage: ") == trained, "not trained again"


@pytest.mark.slow
def test_a_sweep_on_a_local_ray(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    sweep = write_sweep(tmp_path, models="[mlp, cml]")
    out = tmp_path / "runs"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--jobs", "2", "--launcher", "ray",
                     "--out", str(out)]) == 0
    runs = find_runs(out)
    assert len(runs) == 6 and all(r.status().state == "finished" for r in runs)


def test_sweeps_share_the_cells_of_a_common_stage(tmp_path: Path) -> None:
    one = load_sweep(ROOT / "configs/sweeps/table1.yaml", quick=True)
    two = load_sweep(ROOT / "configs/sweeps/table2.yaml", quick=True)
    keys_one = {c.key for c in cells(one, ROOT / "configs/sweeps/table1.yaml")}
    keys_two = {c.key for c in cells(two, ROOT / "configs/sweeps/table2.yaml")}
    shared = {k.split("/")[0] for k in keys_one & keys_two}
    assert shared == {"follow", "carry", "lh1"}  # table2 adds evaluations, not runs
    laptop = load_sweep(ROOT / "configs/sweeps/table1.yaml", preset="laptop")
    comp = load_sweep(ROOT / "configs/sweeps/table1.yaml", preset="laptop_composition")  # extends: laptop
    assert (laptop.phase_b, comp.phase_b) == ("zero_shot", "composition") and comp.eval_trials == 100
    keys_laptop = {c.key for c in cells(laptop, ROOT / "configs/sweeps/table1.yaml")}
    comp_cells = {c.key: c for c in cells(comp, ROOT / "configs/sweeps/table1.yaml")}
    assert {k for k in comp_cells if k.startswith(("follow", "carry"))} <= keys_laptop  # phase A shared
    lh1 = [c for c in comp_cells.values() if c.stage == "lh1"]
    assert {c.model for c in lh1} == {"cml_incremental", "tokenhsi_adapt", "detach"}
    assert not {c.key for c in lh1} & keys_laptop
    assert all("env.subtask_start_prob=0.5" in c.overrides for c in lh1)  # composition only
    for c in lh1:  # each skill taught: the model's own Carry cell, the oracle the rest
        carry = next(k for k in comp_cells if k.startswith(f"carry/{c.model.split('_')[0]}/"))
        assert c.teachers == (("follow", "oracle"), ("carry", carry), ("climb", "oracle"), ("sit", "oracle"))
    assert not any("subtask_start_prob" in o for c in cells(laptop, ROOT / "configs/sweeps/table1.yaml")
                   for o in c.overrides)
    # a stage started from another run weighs the value loss 0.1 (a shared trunk's policy moved
    # with the new task's large value loss); the stage trained from scratch keeps rsl-rl's 1
    # Carry and LH1 also train on the task reward alone on the laptop (the style discriminator
    # saturates on the puppet); the zero-shot LH1 stage is 40 iterations and keeps each
    # checkpoint it saves, the composition stage 100 (its last override wins)
    for c in cells(laptop, ROOT / "configs/sweeps/table1.yaml"):
        assert ("train.value_loss_coef=0.1" in c.overrides) == (c.stage != "follow"), c.key
        assert ("train.amp.style_reward_weight=0" in c.overrides) == (c.stage != "follow"), c.key
        resolved = resolve(c.task, c.model, c.overrides, c.seed, presets=c.presets)
        assert resolved.train.keep_checkpoints.every % resolved.train.save_interval == 0, c.key
        if c.stage == "lh1":
            assert resolved.train.max_iterations == 40 and resolved.train.amp.style_reward_weight == 0
    for c in lh1:  # the composition stage's own settings win over the laptop LH1 stage's
        train = resolve(c.task, c.model, c.overrides, c.seed, presets=c.presets).train
        assert (train.max_iterations, train.save_interval, train.learning_rate) == (100, 5, 1.0e-4)


def _torch_threads(run) -> int:
    return json.loads((run.path / "provenance.json").read_text())["runs"][0]["device"]["torch_threads"]


def test_more_seeds_train_only_the_cells_a_one_seed_sweep_lacks_and_their_table_pools_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)  # the sweep chooses each cell's threads
    cores = os.cpu_count() or 1
    sweep = tmp_path / "one_stage.yaml"
    sweep.write_text(textwrap.dedent(f"""\
        name: one_stage
        models: [mlp]
        seeds: [0]
        table: skills
        stages: [{{name: follow, task: {ROOT / 'configs/tasks/follow.yaml'}}}]
        eval: {{follow: [{ROOT / 'configs/tasks/follow.yaml'}]}}
        presets:
          tiny: {{eval_trials: 2, overrides: [{', '.join(TINY)}]}}
        """))
    out = tmp_path / "runs"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--runs", str(out)]) == 0
    first = {r.status().cell for r in find_runs(out)}
    assert len(first) == 1 and next(iter(first)).startswith("follow/mlp/s0/")
    capsys.readouterr()
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--seeds", "0,1", "--jobs", "2", "--runs", str(out)]) == 0
    said = capsys.readouterr().out
    assert "seeds 0,1: 2 cells, 1 done, 1 to run" in said  # seed 0's cell is the one-seed sweep's
    runs = {r.status().cell: r for r in find_runs(out)}
    assert set(runs) - first == {c.key for c in cells(load_sweep(sweep, preset="tiny", seeds=[1]), sweep)}
    # with --jobs 2 a cell that nothing else can run beside gets every core, two side by side half each
    assert {_torch_threads(r) for k, r in runs.items() if k not in first} == {cores}
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--seeds", "2,3", "--jobs", "2", "--runs", str(out)]) == 0
    pair = [r for r in find_runs(out) if r.status().cell.split("/")[2] in ("s2", "s3")]
    assert len(pair) == 2 and {_torch_threads(r) for r in pair} == {max(1, cores // 2)}
    assert cli.main(["table", str(sweep), "--preset", "tiny", "--seeds", "0,1", "--runs", str(out),
                     "--task", "follow", "--out", str(tmp_path / "tables")]) == 0
    pooled = (tmp_path / "tables" / "one_stage_follow_seeds0-1.csv").read_text()
    assert "4 (2 seeds: s0 " in pooled and "/ s1 " in pooled  # two trials of each seed, each seed's rate
    assert cli.main(["table", str(sweep), "--preset", "tiny", "--runs", str(out), "--task", "follow",
                     "--out", str(tmp_path / "tables")]) == 0
    assert "2 (1 seed: s0)" in (tmp_path / "tables" / "one_stage_follow.csv").read_text()  # the preset's own seeds
    capsys.readouterr()
    for bad, said in [("0,0", "expected distinct seeds, found 0,0"), ("1,x", "expected an integer, found 'x'"),
                      ("-1", "expected an integer in [0, 4294967295], found -1")]:
        assert cli.main(["sweep", str(sweep), "--preset", "tiny", f"--seeds={bad}", "--runs", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0], err
    assert cli.main(["table", str(out), "--seeds", "1"]) == 2
    assert "--seeds: with a sweep file only" in capsys.readouterr().err


def test_a_second_process_on_the_same_sweep_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep = write_sweep(tmp_path)
    out = tmp_path / "runs"
    sweep_cfg = load_sweep(sweep, preset="tiny")
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import time
        from pathlib import Path
        from detach.runs.sweep import _lock_path, file_lock
        key = "sweep:{sweep.resolve()}:{sweep_cfg.preset}:{sweep_cfg.models}:{sweep_cfg.seeds}"
        with file_lock(_lock_path(Path({str(out)!r}), key)) as held:
            print(held, flush=True)
            time.sleep(30)
        """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "True"
        assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--out", str(out)]) == 2
        assert "is already running in another process" in capsys.readouterr().err
    finally:
        holder.kill()


def test_a_locked_cell_is_waited_for_not_run_twice(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    key = "follow/mlp/s0/x"
    with file_lock(_lock_path(out, key)) as held:
        assert held
        with file_lock(_lock_path(out, key), wait_s=0.0) as second:
            assert not second  # another sweep would wait here until the first releases it
    with file_lock(_lock_path(out, key), wait_s=0.0) as again:
        assert again


def test_bad_sweeps_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep = write_sweep(tmp_path, extra="")
    text = sweep.read_text().replace("init_from: carry", "init_from: sit")
    sweep.write_text(text)
    assert cli.main(["sweep", str(sweep), "--out", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "init_from: expected an earlier stage (follow, carry), found 'sit'" in err[0]
    sweep = write_sweep(tmp_path)
    assert cli.main(["sweep", str(sweep), "--preset", "laptopp", "--out", str(tmp_path / "runs")]) == 2
    assert "has no preset 'laptopp'" in capsys.readouterr().err
    assert cli.main(["sweep", str(sweep), "--models", "mlp,detach", "--out", str(tmp_path / "runs")]) == 2
    assert "--models: 'detach' is not a model of sweep 'mini' (mlp)" in capsys.readouterr().err
    sweep = write_sweep(tmp_path, extra="  loop: {extends: loop}\n")
    assert cli.main(["sweep", str(sweep), "--preset", "loop", "--out", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err
    assert "mini.yaml" in err
    assert ("presets.loop.extends: expected another preset of this sweep (laptop, laptop_paper, laptop_composition, "
            "quick, tiny), found 'loop'") in err


def test_a_preset_names_each_skills_teacher_by_stage(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    taught = ("  taught:\n    extends: tiny\n    phase_b: composition\n"
              "    stage_teachers: {lh1: {follow: follow, carry: carry, sit: oracle}}\n")
    sweep = write_sweep(tmp_path, extra=taught)
    plain = {c.stage: c for c in cells(load_sweep(sweep, preset="tiny"), sweep)}
    ones = {c.stage: c for c in cells(load_sweep(sweep, preset="taught"), sweep)}
    assert ones["lh1"].teachers == (("follow", ones["follow"].key), ("carry", ones["carry"].key), ("sit", "oracle"))
    assert ones["carry"].key == plain["carry"].key and ones["lh1"].key != plain["lh1"].key  # phase A shared
    out = tmp_path / "runs"
    assert cli.main(["sweep", str(sweep), "--preset", "taught", "--out", str(out)]) == 0
    runs = {r.status().cell.split("/")[0]: r for r in find_runs(out)}
    teachers = runs["lh1"].config().train.teachers  # pinned to each teacher run's policy file
    assert teachers == {"follow": str(runs["follow"].path.resolve() / "checkpoints" / "model_1.pt"),
                        "carry": str(runs["carry"].path.resolve() / "checkpoints" / "model_1.pt"), "sit": "oracle"}
    for bad, said in [("{lh1: {sit: lh1}}", "presets.bad.stage_teachers.lh1.sit: expected 'oracle' or a stage on "
                                            "lh1's init_from chain (carry, follow), found 'lh1'"),
                      ("{lh1: {sitt: oracle}}", "presets.bad.stage_teachers.lh1.sitt: unknown skill 'sitt'"),
                      ("{lhx: {sit: oracle}}", "presets.bad.stage_teachers.lhx: unknown stage")]:
        sweep = write_sweep(tmp_path, extra=f"  bad: {{extends: tiny, stage_teachers: {bad}}}\n")
        assert cli.main(["sweep", str(sweep), "--preset", "bad", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0], err


def test_a_preset_adds_a_stage_that_takes_over_the_evaluations_of_the_one_it_continues(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    more = ("  more:\n    extends: tiny\n    phase_b: composition\n"
            f"    stages: [{{name: lh1_more, task: {ROOT / 'configs/tasks/lh1.yaml'}, init_from: lh1}}]\n"
            "    stage_overrides: {lh1_more: [train.max_iterations=1]}\n"
            "    stage_teachers: {lh1_more: {follow: lh1, sit: oracle}}\n")
    sweep = write_sweep(tmp_path, extra=more)
    assert [s.name for s in load_sweep(sweep, preset="tiny").stages] == ["follow", "carry", "lh1"]
    out = tmp_path / "runs"
    assert cli.main(["sweep", str(sweep), "--preset", "more", "--out", str(out)]) == 0
    runs = {r.status().cell.split("/")[0]: r for r in find_runs(out)}
    lh1, more = runs["lh1"], runs["lh1_more"]
    assert sorted(p.name for p in more.path.glob("eval*.json")) == ["eval.test.json", "eval_lh2.test.json"]
    assert not list(lh1.path.glob("eval*.json"))  # its evaluations went to the stage continuing it
    config = more.config()
    assert config.train.max_iterations == 1 and config.train.init_from.startswith(str(lh1.path.resolve()))
    assert config.train.teachers == {"follow": str(lh1.path.resolve() / "checkpoints" / "model_1.pt"), "sit": "oracle"}
    capsys.readouterr()
    assert cli.main(["table", str(sweep), "--preset", "more", "--runs", str(out), "--out", str(tmp_path / "t")]) == 0
    assert "(0 evaluations" not in capsys.readouterr().out
    assert (tmp_path / "t" / "mini.csv").read_text().count("\n") == 2  # header + the continued policy's row
    lh1_task = ROOT / "configs/tasks/lh1.yaml"
    for bad, said in [(f"[{{name: lh1, task: {lh1_task}, init_from: carry}}]",
                       "presets.bad.stages[0].name: expected a new stage name, found 'lh1'"),
                      (f"[{{name: lh1_more, task: {lh1_task}}}]",
                       "presets.bad.stages[0].init_from: expected the stage this one continues (follow, carry, lh1), "
                       "found None"),
                      (f"[{{name: lh1_more, task: {lh1_task}, init_from: sit}}]",
                       "presets.bad.stages[0].init_from: expected the stage this one continues (follow, carry, lh1), "
                       "found 'sit'")]:
        sweep = write_sweep(tmp_path, extra=f"  bad: {{extends: tiny, stages: {bad}}}\n")
        assert cli.main(["sweep", str(sweep), "--preset", "bad", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and said in err[0], err


def test_init_from_refuses_another_architecture_naming_both_models(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    follow = str(ROOT / "configs/tasks/follow.yaml")
    assert cli.main([follow, "--model", "mlp", "--out", str(tmp_path), "--no-eval", *TINY]) == 0
    source = find_runs(tmp_path)[0]
    capsys.readouterr()
    code = cli.main([follow, "--model", "tokenhsi", "--out", str(tmp_path / "b"), "--no-eval", *TINY,
                     f"train.init_from={source.path}"])
    assert code == 2  # a user error found while building: the run is marked failed with the reason
    run = find_runs(tmp_path / "b")[0]
    assert run.status().state == "failed"
    assert "holds model mlp (mlp), which does not fit this run's model tokenhsi (tokenhsi)" in run.status().error
    assert cli.main([follow, "--model", "mlp", "--out", str(tmp_path / "c"), "--dry-run", *TINY,
                     "train.init_from=/nowhere/run"]) == 2
    assert "train.init_from: /nowhere/run is neither a run folder nor a checkpoint file" in capsys.readouterr().err
    for model, key in (("tokenhsi_adapt", "model.adapt_skills"), ("cml_incremental", "model.incremental")):
        assert cli.main([follow, "--model", model, "--out", str(tmp_path / "d"), "--dry-run", *TINY]) == 2
        err = capsys.readouterr().err
        assert f"{model}.yaml" in err and key in err and "set train.init_from" in err, err
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("normalizers", ["keep", "restart"])
def test_init_from_copies_weights_normalisers_and_discriminator(tmp_path: Path, normalizers: str) -> None:
    from detach.config import resolve
    from detach.train.setup import build_runner, load_initial_weights

    follow = ROOT / "configs/tasks/follow.yaml"
    assert cli.main([str(follow), "--model", "mlp", "--out", str(tmp_path / "a"), "--no-eval", *TINY]) == 0
    source = find_runs(tmp_path / "a")[0]
    saved = torch.load(source.latest_checkpoint(), weights_only=True)
    cfg = resolve(ROOT / "configs/tasks/carry.yaml", "mlp", [*TINY, f"train.init_from={source.path}",
                                                             f"train.init_normalizers={normalizers}"])
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    before = {k: v.clone() for k, v in runner.alg.actor.state_dict().items()}
    assert "initialised from" in load_initial_weights(runner, cfg)
    actor = runner.alg.actor.state_dict()
    assert any(not torch.equal(before[k], actor[k]) for k in actor)
    weights = [k for k in actor if "normalizer" not in k]
    assert all(torch.equal(actor[k], saved["actor_state_dict"][k]) for k in weights)
    stats = [k for k in actor if "normalizer" in k]
    assert stats and all(torch.equal(actor[k], saved["actor_state_dict"][k]) == (normalizers == "keep")
                         or torch.equal(saved["actor_state_dict"][k], before[k]) for k in stats)
    disc = runner.alg.discriminators.state_dict()
    assert all(torch.equal(disc[k], saved["discriminator_state_dict"][k]) for k in disc)
    assert runner.completed_iteration == -1, "a run started from another one counts its own iterations"


def test_sigterm_to_a_sweep_interrupts_its_running_cell_and_ends_the_sweep(tmp_path: Path) -> None:
    """`kill SWEEP_PID` (a scheduler's stop) reaches the cell being trained: it checkpoints and
    is `interrupted`, and the sweep exits 130 at once instead of waiting for the cell to end."""
    long = [*TINY[:-1], "train.max_iterations=100000", "train.save_interval=100000"]
    sweep = write_sweep(tmp_path, extra=f"  long: {{eval_trials: 2, overrides: [{', '.join(long)}]}}\n")
    out = tmp_path / "runs"
    proc = subprocess.Popen([sys.executable, "-m", "detach.cli", "--sweep", str(sweep), "--preset", "long",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:  # until the cell has trained an iteration
            runs = find_runs(out)
            if runs and runs[0].status().iteration >= 1:
                break
            time.sleep(0.5)
        else:
            pytest.fail("the sweep's cell never trained an iteration")
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=90)
    finally:
        proc.kill()
    assert code == 130, proc.stderr.read()
    status = find_runs(out)[0].status()
    assert status.state == "interrupted", status
    assert status.iteration < 100000
    assert list((find_runs(out)[0].path / "checkpoints").glob("model_*.pt"))
