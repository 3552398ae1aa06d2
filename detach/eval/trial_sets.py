"""Which start states an evaluation plays: three disjoint sets of trials per run seed.

A figure measured on the trials a recipe was tuned on is not a result, so each run seed S has
three sets, each an evaluation env seeded differently (the env's generator draws every start):

- `development` (env seed S): what `detach-run eval` and `train` play by default, and what
  every probe and diagnosis compares (every evaluation before trial sets existed played it);
- `validation` (S + `VALIDATION_SEED_OFFSET`): what a run chooses on (its start, its
  checkpoint), never reported;
- `test` (S + the sweep's `test_seed_offset`): the final tables only. It is played only for a
  sweep cell, through the sweep, and written to files of its own (`eval.test.json`), so no
  probe can overwrite or read it by accident.

The test offset is at least `MIN_TEST_SEED_OFFSET`, so test seeds of the run seeds in use
(below that) never meet another set's seed of any such run seed.
"""

from __future__ import annotations

from typing import Literal

TrialSet = Literal["development", "validation", "test"]
TRIAL_SETS: tuple[TrialSet, ...] = ("development", "validation", "test")

VALIDATION_SEED_OFFSET = 7919
"""The validation env's seed is the run's plus this."""
MIN_TEST_SEED_OFFSET = 1_000_000
"""Test offsets start here: far above the validation offset and the run seeds in use."""


class TrialSetError(ValueError):
    """An evaluation asked for trials it may not play."""


def check_test_offset(offset: int) -> int:
    """The test offset, refused where its seeds could meet another set's."""
    if isinstance(offset, bool) or not isinstance(offset, int) or offset < MIN_TEST_SEED_OFFSET:
        raise TrialSetError(f"expected a test seed offset of at least {MIN_TEST_SEED_OFFSET:,} (an integer), "
                            f"found {offset!r}")
    return offset


def trial_seed(run_seed: int, trial_set: TrialSet, test_offset: int | None = None) -> int:
    """The evaluation env's seed of `trial_set` for a run of seed `run_seed`."""
    if trial_set == "development":
        return int(run_seed)
    if trial_set == "validation":
        return int(run_seed) + VALIDATION_SEED_OFFSET
    if trial_set == "test":
        if test_offset is None:
            raise TrialSetError("the test trials need the sweep's test_seed_offset")
        return int(run_seed) + check_test_offset(test_offset)
    raise TrialSetError(f"unknown trial set {trial_set!r}; expected one of {', '.join(TRIAL_SETS)}")


def describe(trial_set: str, test_offset: int | None = None) -> str:
    """One line for a table: which trials its cells played."""
    if trial_set == "test":
        offset = f" + {test_offset:,}" if test_offset is not None else " + the sweep's test offset"
        return f"Trials: test set (held out: env seed = run seed{offset}; never used for tuning or choosing)."
    return ("Trials: development set (env seed = run seed; the trials probes and diagnoses compare on, "
            "not a held-out figure).")
