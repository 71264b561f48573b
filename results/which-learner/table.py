"""The "which learner when" table from run records: ``python results/which-learner/table.py DIR``.

DIR holds one folder of run records (``<key>.json``, as ``factirl-opt bench which-learner`` writes
them under ``OUT/<preset>/runs``) per preset; every point and seed found is compared with the
library's own verdicts (``factirl_opt.lab.experiments.claims.sharing_verdicts``, the bench's
margins), whatever code computed it (each record names its code in ``provenance``).
"""
import glob
import json
import os
import sys

from factirl_opt.lab.benchmarks.which_learner import sharing_table
from factirl_opt.lab.experiments.claims import SHARING_MARGINS, sharing_verdicts

results = {}
for folder in sorted(glob.glob(os.path.join(sys.argv[1], "*"))):
    rows = [row for f in sorted(glob.glob(os.path.join(folder, "*.json"))) for row in json.load(open(f))["rows"]]
    if not rows:
        continue
    column = "success_rate" if any(r.get("success_rate") is not None for r in rows) else "deviation"
    chosen = {(r["n_tasks"], r["demos_per_task"], r["seed"]): (r["n_primitives"], r["residual_penalty"])
              for r in rows if r["split"] == "test" and "n_primitives" in r}
    verdicts = [dict(v, n_primitives=chosen[key][0], residual_penalty=chosen[key][1])
                for v in sharing_verdicts(rows, "test", column) for key in [(v["n_tasks"], v["demos_per_task"], v["seed"])]]
    results[os.path.basename(folder)] = {"column": column, "verdicts": verdicts}
print(f"Score: deviation (no worse: within {SHARING_MARGINS['deviation']:.0%} of the better of flat and factorial) "
      f"or success rate (no worse: within {SHARING_MARGINS['success_rate']}).\n")
print(sharing_table(results))
n = sum(len(r["verdicts"]) for r in results.values())
print(f"no worse: {sum(v['no_worse'] for r in results.values() for v in r['verdicts'])}/{n}; "
      f"beats both: {sum(v['beats_both'] for r in results.values() for v in r['verdicts'])}/{n}")
