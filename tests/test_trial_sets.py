"""Held-out test trials: three disjoint sets of start states per run seed, the test set played
only for a sweep's cells and read only by its tables; each table row names its aids."""

from __future__ import annotations

import csv
import dataclasses
import json
import re
import textwrap
from pathlib import Path

import pytest

from detach import cli
from detach.config import resolve
from detach.eval.aids import run_aids
from detach.eval.trial_sets import MIN_TEST_SEED_OFFSET, TrialSetError, trial_seed
from detach.runfolder.folder import find_runs
from detach.runfolder.names import eval_file, trial_set_of_file
from detach.runs.validation import validation_seed

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "train.max_iterations=2"]
OFFSET = 1_000_003


def test_the_three_sets_never_share_a_seed_across_the_run_seeds_in_use() -> None:
    seeds = range(0, 200)
    dev = {trial_seed(s, "development") for s in seeds}
    val = {trial_seed(s, "validation") for s in seeds}
    test = {trial_seed(s, "test", OFFSET) for s in seeds}
    assert not dev & val and not dev & test and not val & test
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", ["env.character=puppet"], seed=3)
    assert validation_seed(cfg) == trial_seed(3, "validation")  # validation never reads the test offset
    for bad in (None, 0, 7919, MIN_TEST_SEED_OFFSET - 1, True):
        with pytest.raises(TrialSetError):
            trial_seed(0, "test", bad)
    assert eval_file(None, "test") == "eval.test.json" and eval_file("lh2", "test") == "eval_lh2.test.json"
    assert eval_file("lh2") == "eval_lh2.json" and trial_set_of_file("eval_lh2.json") == "development"


def test_nothing_outside_the_sweep_passes_the_test_offset() -> None:
    """Probes, diagnoses, choices and examples evaluate on development or validation trials
    only: the flag and the call that play the test trials appear in the sweep's job, the
    CLI that parses it, the API and the session that run it, nowhere else."""
    allowed = {"detach/runs/sweep_jobs.py", "detach/cli.py", "detach/runs/actions.py", "detach/runs/resume_policy.py",
               "detach/runs/session.py", "detach/eval/trial_sets.py",
               "detach/runfolder/names.py", "detach/runs/tables_cli.py", "detach/runs/ship.py"}
    pattern = re.compile(r"--test-trials|test_offset\s*=|trial_seed\([^)]*[\"']test[\"']")
    offenders = []
    for folder in ("detach", "server", "examples", "benchmarks", "results"):
        for path in (ROOT / folder).rglob("*.py"):
            rel = path.relative_to(ROOT).as_posix()
            if rel not in allowed and pattern.search(path.read_text(errors="replace")):
                offenders.append(rel)
    assert not offenders, f"play the test trials outside the sweep: {offenders}"


def _one_stage_sweep(tmp_path: Path, offset: int | str = OFFSET) -> Path:
    sweep = tmp_path / "one_stage.yaml"
    sweep.write_text(textwrap.dedent(f"""\
        name: one_stage
        models: [mlp]
        seeds: [0]
        table: skills
        test_seed_offset: {offset}
        stages: [{{name: follow, task: {ROOT / 'configs/tasks/follow.yaml'}}}]
        eval: {{follow: [{ROOT / 'configs/tasks/follow.yaml'}]}}
        presets:
          tiny: {{eval_trials: 2, overrides: [{', '.join(TINY)}]}}
          tiny_taught: {{eval_trials: 2, overrides: [{', '.join(TINY)}, train.select_checkpoint_trials=2,
                                                     train.save_interval=1]}}
        """))
    return sweep


def test_a_sweep_evaluates_its_cells_on_the_test_trials_and_its_table_reads_only_those(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep, out, tables = _one_stage_sweep(tmp_path), tmp_path / "runs", tmp_path / "tables"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--runs", str(out)]) == 0
    (run,) = find_runs(out)
    assert not (run.path / "eval.json").exists()
    test = json.loads((run.path / "eval.test.json").read_text())
    assert test["trial_set"] == "test" and test["trial_seed"] == OFFSET and test["aids"] == []
    # a probe of the same run plays the development trials, into eval.json
    assert cli.main(["eval", str(run.path), "--trials", "2"]) == 0
    dev = json.loads((run.path / "eval.json").read_text())
    assert dev["trial_set"] == "development" and dev["trial_seed"] == 0
    # the test trials are refused outside a sweep cell: a hand-made run, and its evaluation
    capsys.readouterr()
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(tmp_path / "probe"), "--test-trials",
                     str(OFFSET), *TINY]) == 2
    assert "only for a sweep's cells" in capsys.readouterr().err
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(tmp_path / "probe"), "--trials", "2",
                     *TINY]) == 0
    (probe,) = find_runs(tmp_path / "probe")
    capsys.readouterr()
    assert cli.main(["eval", str(probe.path), "--trials", "2", "--test-trials", str(OFFSET)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "only for a sweep's cells" in err[0]
    assert not (probe.path / "eval.test.json").exists()
    # the sweep's table: the test trials, labelled; --trial-set development: the probes' set
    assert cli.main(["table", str(sweep), "--preset", "tiny", "--runs", str(out), "--task", "follow",
                     "--out", str(tables)]) == 0
    md = (tables / "one_stage_follow.md").read_text()
    assert "Trials: test set" in md and "1,000,003" in md and "| MLP |" in md
    assert cli.main(["table", str(sweep), "--preset", "tiny", "--runs", str(out), "--task", "follow",
                     "--trial-set", "development", "--out", str(tables)]) == 0
    assert "Trials: development set" in (tables / "one_stage_follow_dev.md").read_text()


def test_a_table_row_names_its_aids_and_marks_a_recipe_chosen_after_a_test_evaluation(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep, out, tables = _one_stage_sweep(tmp_path), tmp_path / "runs", tmp_path / "tables"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--runs", str(out)]) == 0
    # another recipe of the same stage, model and seed, trained after the first one's test evaluation
    assert cli.main(["sweep", str(sweep), "--preset", "tiny_taught", "--runs", str(out)]) == 0
    assert cli.main(["table", str(sweep), "--preset", "tiny_taught", "--runs", str(out), "--task", "follow",
                     "--out", str(tables)]) == 0
    rows = list(csv.DictReader((tables / "one_stage_follow.csv").open()))
    assert [r["method"] for r in rows] == ["MLP + chosen checkpoint + recipe chosen after a test evaluation"]
    assert "follow_s0" in rows[0] and rows[0]["follow_s0"] == rows[0]["follow"]
    # the first recipe was evaluated on the test trials before any other: no mark
    assert cli.main(["table", str(sweep), "--preset", "tiny", "--runs", str(out), "--task", "follow",
                     "--out", str(tables)]) == 0
    assert [r["method"] for r in csv.DictReader((tables / "one_stage_follow.csv").open())] == ["MLP"]


def test_a_sweep_table_says_which_code_trained_its_cells(tmp_path: Path) -> None:
    """A cell key digests the config, not the code: cells of one key trained in two sessions
    under different code pool into one row, so the table names the commits."""
    sweep, out, tables = _one_stage_sweep(tmp_path), tmp_path / "runs", tmp_path / "tables"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--seeds", "0,1", "--runs", str(out)]) == 0
    runs = sorted(find_runs(out), key=lambda r: r.path.name)
    assert len(runs) == 2

    def trained_at(run, commit: str, diff: str = "") -> None:
        record = {"time": "2026-12-07T00:00:00+00:00", "git": {"commit": commit, "diff": diff}}
        run.provenance_path.write_text(json.dumps({"runs": [record]}))

    table = ["table", str(sweep), "--preset", "tiny", "--seeds", "0,1", "--runs", str(out), "--task", "follow",
             "--out", str(tables)]
    for run in runs:
        trained_at(run, "a" * 40)
    assert cli.main(table) == 0
    md = (tables / "one_stage_follow_seeds0-1.md").read_text()
    assert "Code: the sweep's 2 cells in the runs folder: trained at commit aaaaaaa." in md
    trained_at(runs[1], "b" * 40, diff="diff --git a/x b/x")
    assert cli.main(table) == 0
    md = (tables / "one_stage_follow_seeds0-1.md").read_text()
    assert ("trained at 2 commits, aaaaaaa (1 cell), bbbbbbb with uncommitted changes (1 cell); a cell's key "
            "digests its config, not the code") in md


def test_aids_come_from_the_config() -> None:
    def aids(*overrides: str) -> list[str]:
        return run_aids(resolve(ROOT / "configs/tasks/lh1.yaml", "detach", ["env.character=puppet", *overrides]))

    assert aids() == []
    assert aids("train.amp.style_reward_weight=0") == ["no style reward"]
    assert aids("+train.teachers.sit=oracle", "env.subtask_start_prob=0.5", "train.select_checkpoint_trials=50",
                "+rewards.terms.sit/seat_precision=0.5") == [
        "oracle teacher", "oracle-recorded starts", "chosen checkpoint", "added reward terms"]
    assert aids("train.init_action_mean={grasp: 0.1}", "train.critic_warmup_iterations=5") == [
        "set start pose", "critic warm-up"]
    assert aids("train.balance_assist.torque=1000") == ["balance assist"]
    assert aids("rewards.power_coeff=0") == ["no power penalty"]  # the paper's 0.0005 x W, dropped
    assert aids("rewards.power_coeff=0.0001") == ["power penalty x0.2"]
    tokenhsi = resolve(ROOT / "configs/tasks/carry.yaml", "tokenhsi", ["env.character=puppet"])
    started = dataclasses.replace(tokenhsi, train=dataclasses.replace(tokenhsi.train, init_from="runs/x"))
    assert run_aids(tokenhsi) == [] and run_aids(started) == ["copied tokenizer"]


def test_a_test_offset_that_could_meet_another_set_is_a_one_line_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep = _one_stage_sweep(tmp_path, offset=7919)
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--runs", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "test_seed_offset" in err[0] and "at least 1,000,000" in err[0], err


def test_an_exported_policy_is_evaluated_without_its_run_folder_on_the_same_trials(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep, out = _one_stage_sweep(tmp_path), tmp_path / "runs"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--runs", str(out)]) == 0
    (run,) = find_runs(out)
    shipped = tmp_path / "shipped"
    shipped.mkdir()
    policy = shipped / "follow_mlp_s0.policy.pt"
    assert cli.main(["export", str(run.path), "--format", "policy", "--output", str(policy)]) == 0
    info = json.loads((shipped / "follow_mlp_s0.policy.json").read_text())
    assert info["format"] == "policy" and info["cell"] == run.status().cell and info["seed"] == 0
    assert "critic_state_dict" not in __import__("torch").load(policy, weights_only=True)
    import shutil

    shutil.rmtree(out)  # the run folder is gone: the policy file and its two descriptions suffice
    assert cli.main(["eval", str(policy), "--task", "follow", "--trials", "2", "--test-trials", str(OFFSET)]) == 0
    result = json.loads((shipped / "follow_mlp_s0.policy.eval_follow_s0.test.json").read_text())
    assert result["trial_set"] == "test" and result["trial_seed"] == OFFSET and result["trials"] == 2
    assert cli.main(["eval", str(policy), "--task", "follow", "--seed", "1", "--trials", "2"]) == 0
    other = json.loads((shipped / "follow_mlp_s0.policy.eval_follow_s1.json").read_text())
    assert other["trial_set"] == "development" and other["trial_seed"] == 1 and other["seed"] == 1
    # a policy that was not a sweep cell's may not play the test trials
    info["cell"] = None
    (shipped / "follow_mlp_s0.policy.json").write_text(json.dumps(info))
    capsys.readouterr()
    assert cli.main(["eval", str(policy), "--trials", "2", "--test-trials", str(OFFSET)]) == 2
    assert "only for a sweep cell's policy" in capsys.readouterr().err


def test_the_dashboard_counts_a_run_evaluated_on_both_sets_once() -> None:
    from server.table_views import build_tables
    from tests.test_eval_tables import LH1, _evals

    dev = _evals("lh1", "detach", LH1, [[1, 1, 0, 0]] * 4, [False] * 4)
    test = _evals("lh1", "detach", LH1, [[1, 0, 0, 0]] * 6, [False] * 6)
    test.trial_set = "test"
    skills = build_tables([("run", dev), ("run", test)])["skills"].table
    n_col = skills.header.index("n")
    assert [str(r[n_col]) for r in skills.rows] == ["6 (1 seed: s0)"]  # the test trials alone
    assert build_tables([("run", dev)])["skills"].table.rows[0][n_col] == "4 (1 seed: s0)"


def test_table_one_measures_zero_shot_climb_and_sit_where_every_trial_starts_at_them() -> None:
    from detach.runs.sweep_config import load_sweep
    from detach.runs.sweep_graph import cells

    sweep = ROOT / "configs/sweeps/table1.yaml"
    for preset in ("laptop", "laptop_paper"):
        lh1 = [c for c in cells(load_sweep(sweep, preset=preset), sweep) if c.stage == "lh1"]
        assert lh1 and all([t.stem for t in c.evals] == ["lh1", "climb", "sit"] for c in lh1)
        assert all(c.trial_set == "test" for c in lh1)


def test_a_sweeps_policies_ship_with_a_manifest_whose_figures_eval_repeats(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sweep, out, shipped = _one_stage_sweep(tmp_path), tmp_path / "runs", tmp_path / "policies"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--runs", str(out)]) == 0
    (run,) = find_runs(out)
    assert cli.main(["export", str(sweep), "--preset", "tiny", "--stage", "follow", "--runs", str(out),
                     "--output", str(shipped), "--format", "policy"]) == 0
    manifest = json.loads((shipped / "manifest.json").read_text())
    (entry,) = manifest["policies"]
    assert entry["cell"] == run.status().cell and entry["file"] == "one_stage_tiny_follow_mlp_s0.policy.pt"
    assert entry["config_digest"] == entry["cell"].rsplit("/", 1)[1] and entry["sha256"]
    (figure,) = entry["figures"]
    assert figure["trial_set"] == "test" and figure["trial_seed"] == OFFSET and figure["trials"] == 2
    assert [f["task"] for f in entry["cell_figures"]] == ["follow"]  # the float32 cell's own, beside it
    assert (shipped / "manifest.md").read_text().count("one_stage_tiny_follow_mlp_s0.policy.pt") == 1
    # the manifest's figure, repeated from the shipped file alone
    before = (shipped / "one_stage_tiny_follow_mlp_s0.policy.eval_follow_s0.test.json").read_text()
    (shipped / "one_stage_tiny_follow_mlp_s0.policy.eval_follow_s0.test.json").unlink()
    assert cli.main(["eval", str(shipped / entry["file"]), "--task", "follow", "--trials", "2",
                     "--test-trials", str(OFFSET)]) == 0
    again = json.loads((shipped / "one_stage_tiny_follow_mlp_s0.policy.eval_follow_s0.test.json").read_text())
    first = json.loads(before)
    assert again["lh_mean"] == first["lh_mean"] and again["trial_scores"] == first["trial_scores"]
    capsys.readouterr()
    assert cli.main(["export", str(sweep), "--preset", "tiny", "--runs", str(out), "--output", str(shipped)]) == 2
    assert "--stage" in capsys.readouterr().err


def test_shipping_into_a_folder_of_another_presets_policies_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A second preset's export into the same --output would overwrite the manifest of the
    policies already there (they would lose their figures); it is refused, nothing written."""
    sweep, out, shipped = _one_stage_sweep(tmp_path), tmp_path / "runs", tmp_path / "policies"
    assert cli.main(["sweep", str(sweep), "--preset", "tiny", "--runs", str(out)]) == 0
    shipped.mkdir()
    other = {"sweep": "one_stage", "preset": "laptop_paper", "stage": "follow", "policies": [{"file": "x.policy.pt"}]}
    (shipped / "manifest.json").write_text(json.dumps(other))
    capsys.readouterr()
    assert cli.main(["export", str(sweep), "--preset", "tiny", "--stage", "follow", "--runs", str(out),
                     "--output", str(shipped), "--format", "policy"]) == 2
    err = capsys.readouterr().err
    assert "laptop_paper" in err and "--output" in err
    assert json.loads((shipped / "manifest.json").read_text()) == other
    assert not list(shipped.glob("*.policy.pt"))
