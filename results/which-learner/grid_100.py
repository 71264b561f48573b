"""Compute the small points of sharing-grid (5 and 20 tasks, seeds 0-2) as the runner would, into a staging runs/ dir."""
import sys, warnings
from factirl_opt.lab.experiments import PRESETS
from factirl_opt.lab.experiments.learners import get_lineup
from factirl_opt.lab.experiments.runner import RunSpec, run_one
from factirl_opt.lab.experiments import store
preset = PRESETS["sharing-grid"]; lineup = get_lineup(preset.lineup)
expected = store.expected_provenance(preset, lineup)
for n in (100,):
    for s in (0,):
        spec = RunSpec(n, 10, s, preset.solvers)
        rec = run_one(preset, spec)
        rec = store.seal(rec, expected, "grid-100-20261126")
        store.write_record(sys.argv[1], rec)
        print("done", rec["key"], flush=True)
