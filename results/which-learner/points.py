"""Some points of a which-learner preset (``sharing-grid`` by default), computed and sealed as the runner
does, into a runs/ directory that ``factirl-opt bench which-learner`` and ``table.py`` read:

    python results/which-learner/points.py RUNS_DIR --tasks 5 20 --seeds 0 1 2
    python results/which-learner/points.py RUNS_DIR --preset sharing-babyai --tasks 30 --seeds 1 2

(the bench runs every point of a preset, the largest first; this runs the ones asked for).

The diagnostics with other numbers of folds (``diagnostics/folds5-objectworld-quick-20``, and the 20
folds of docs/maths.md) were run by this script's former ``--folds K``, which overwrote the library's
module constant (commit 27407ca); a search with K folds is now ``FactIRL(sharing_search=SharingSearch(cv=K))``,
and ``foldscores.py`` scores candidates on the search's folds through the public
``adaptive.task_folds`` / ``adaptive.score_candidates``.
"""
import argparse
import os

from factirl_opt.lab.experiments import PRESETS, store
from factirl_opt.lab.experiments.learners import get_lineup
from factirl_opt.lab.experiments.runner import RunSpec, run_one

parser = argparse.ArgumentParser()
parser.add_argument("runs_dir")
parser.add_argument("--tasks", type=int, nargs="+", required=True)
parser.add_argument("--seeds", type=int, nargs="+", required=True)
parser.add_argument("--preset", default="sharing-grid")
args = parser.parse_args()
os.makedirs(args.runs_dir, exist_ok=True)  # before the runs: a record is never computed and then lost
preset = PRESETS[args.preset]
expected = store.expected_provenance(preset, get_lineup(preset.lineup))
for n in args.tasks:
    for s in args.seeds:
        rec = run_one(preset, RunSpec(n, preset.default_demos, s, preset.solvers))
        store.write_record(args.runs_dir, store.seal(rec, expected, f"{preset.name}-{n}-seed{s}"))
        print("done", rec["key"], flush=True)
