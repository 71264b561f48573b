"""Reproduction of the paper's experiments (section 4, figures 1-3).

Presets are data (:mod:`.presets`); one runner executes them (:mod:`.runner`); figures are drawn
from the tables it writes (:mod:`.figures`). From the command line::

    factirl-opt reproduce --preset quick --out runs/quick
    factirl-opt plot runs/quick
"""

from .ground_truth import GroundTruth, make_ground_truth
from .presets import PRESETS, Preset, get_preset
from .runner import RunSpec, TEST_LEARNERS, TRAIN_LEARNERS, plan_runs, read_csv, run_one, run_sweep, write_tables

__all__ = [
    "Preset",
    "PRESETS",
    "get_preset",
    "GroundTruth",
    "make_ground_truth",
    "RunSpec",
    "TRAIN_LEARNERS",
    "TEST_LEARNERS",
    "plan_runs",
    "run_one",
    "run_sweep",
    "write_tables",
    "read_csv",
]
