"""Some points of the ``sharing-grid`` preset, computed and sealed as the runner does, into a runs/ directory
that ``factirl-opt bench which-learner`` and ``table.py`` read:

    python results/which-learner/grid_points.py RUNS_DIR --tasks 5 20 --seeds 0 1 2

(the bench runs every point of a preset, the 100-task one first; this runs the ones asked for).
"""
import argparse

from factirl_opt.lab.experiments import PRESETS, store
from factirl_opt.lab.experiments.learners import get_lineup
from factirl_opt.lab.experiments.runner import RunSpec, run_one

parser = argparse.ArgumentParser()
parser.add_argument("runs_dir")
parser.add_argument("--tasks", type=int, nargs="+", required=True)
parser.add_argument("--seeds", type=int, nargs="+", required=True)
args = parser.parse_args()
preset = PRESETS["sharing-grid"]
expected = store.expected_provenance(preset, get_lineup(preset.lineup))
for n in args.tasks:
    for s in args.seeds:
        rec = run_one(preset, RunSpec(n, 10, s, preset.solvers))
        store.write_record(args.runs_dir, store.seal(rec, expected, f"grid-{n}-seed{s}"))
        print("done", rec["key"], flush=True)
