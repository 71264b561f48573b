"""The "which learner when" table from run records: ``python results/which-learner/table.py DIR``.

DIR holds one folder of run records (``<key>.json``, as ``factirl-opt bench which-learner`` writes
them under ``OUT/<preset>/runs``) per preset; every point and seed found is compared with the
library's own verdicts (``factirl_opt.lab.benchmarks.which_learner.benchmark_verdicts``, the bench's
margins), whatever code computed it (each record names its code in ``provenance``).
"""
import glob
import json
import os
import sys

from factirl_opt.lab.benchmarks.which_learner import benchmark_verdicts, sharing_table
from factirl_opt.lab.experiments.claims import SHARING_MARGINS

results = {}
for folder in sorted(glob.glob(os.path.join(sys.argv[1], "*"))):
    rows = [row for f in sorted(glob.glob(os.path.join(folder, "*.json"))) for row in json.load(open(f))["rows"]]
    if rows:
        results[os.path.basename(folder)] = benchmark_verdicts(rows)
print(f"Score: deviation (no worse: within {SHARING_MARGINS['deviation']:.0%} of the better of flat and factorial) "
      f"or success rate (no worse: within {SHARING_MARGINS['success_rate']}).\n")
print(sharing_table(results))
n = sum(len(r["verdicts"]) for r in results.values())
print(f"no worse: {sum(v['no_worse'] for r in results.values() for v in r['verdicts'])}/{n}; "
      f"beats both: {sum(v['beats_both'] for r in results.values() for v in r['verdicts'])}/{n}")
