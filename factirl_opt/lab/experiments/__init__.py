"""Reproduction of the paper's experiments (section 4, figures 1-3).

Module map:

- :mod:`.presets`: experiment configurations as data (``paper``, ``fast``, ``quick``, ``test``,
  ``tiny``, ``objectworld``, ``objectworld-quick``, ``objectworld-tiny``,
  ``objectworld-per-task``, ``objectworld-per-task-quick``), with their planner and the
  factorial learner's default solvers;
- :mod:`.worlds`: a run's ground truth (world, true tasks, demonstrations, base features) per
  world (``"grid"``, ``"objectworld"``, ``"objectworld-per-task"``: a map per task);
- :mod:`.learner_names`: the learners' names, as constants;
- :mod:`.learners`: the learner line-ups as data (named builders: ``"paper"``,
  ``"objectworld"``, both ``+mce``, and ``"objectworld-per-task"``);
- :mod:`.learner_solvers`: which solvers each learner takes;
- :mod:`.per_task`: the learners of the world with a map per task and their scores on fresh maps;
- :mod:`.runner`: plan the runs of a preset (:func:`plan_sweep`) and execute them
  (:func:`run_plan`; :func:`run_sweep` does both);
- :mod:`.store`: the checked run cache, the lock and the manifest;
- :mod:`.workers`: worker processes that never outlive the sweep;
- :mod:`.tables`: the CSV tables written from the run records, read back;
- :mod:`.claims`: each line-up's claims evaluated on the tables;
- :mod:`.figures`: figures 1-3 drawn from the tables.

The path from the command line to the figures, each stage taking the previous one's output::

    preset = get_preset("quick")                       # or dataclasses.replace(preset, ...)
    plan = plan_sweep(preset, seeds=[0], solvers=preset.solvers.with_overrides(h_solver="lbfgs"))
    result = run_plan(plan, "runs/quick", Execution(jobs=2))   # runs, store, tables
    plot_all("runs/quick"); write_claims("runs/quick", preset)  # figures and claims

From the command line::

    factirl-opt reproduce --preset quick --out runs/quick
    factirl-opt reproduce --preset objectworld-quick --out runs/objectworld-quick
    factirl-opt reproduce --preset objectworld-per-task-quick --out runs/objectworld-per-task-quick
    factirl-opt reproduce --preset paper --lineup paper+mce --jobs 2 --out runs/paper-mce
    factirl-opt plot runs/quick
"""

from .babyai_figure import babyai_figure_data, plot_babyai_layout
from .claims import claims_markdown, evaluate_claims, write_claims
from .figures import plot_all, plot_sweeps, plot_value_functions
from .learners import LINEUPS, Learner, Lineup, get_lineup
from .presets import PRESETS, Preset, get_preset
from .runner import Execution, RunSpec, SweepPlan, plan_runs, plan_sweep, run_one, run_plan, run_sweep
from .tables import read_csv, write_tables
from .worlds import WORLDS, GroundTruth, make_ground_truth

#: learner names of the paper's line-up, per split (figure 1: train; figure 2: test)
TRAIN_LEARNERS = LINEUPS["paper"].names("train")
TEST_LEARNERS = LINEUPS["paper"].names("test")

__all__ = [
    "Preset",
    "PRESETS",
    "get_preset",
    "GroundTruth",
    "WORLDS",
    "make_ground_truth",
    "Learner",
    "Lineup",
    "LINEUPS",
    "get_lineup",
    "RunSpec",
    "SweepPlan",
    "Execution",
    "plan_sweep",
    "run_plan",
    "TRAIN_LEARNERS",
    "TEST_LEARNERS",
    "plan_runs",
    "run_one",
    "run_sweep",
    "write_tables",
    "read_csv",
    "evaluate_claims",
    "claims_markdown",
    "write_claims",
    "plot_sweeps",
    "plot_value_functions",
    "plot_all",
    "babyai_figure_data",
    "plot_babyai_layout",
]
