"""The evidence route's search with candidate fits of B outer iterations instead of PCA starts, on one
which-learner point (run from the repository's root; several budgets in one process draw their folds
one after the other from the learner's rng, so only the first shares the benchmark's folds):
python results/which-learner/diagnostics/evidence-budget/budget.py PRESET N SEED OUT.json B [B ...]"""
import json, sys, time
sys.path.insert(0, "results/which-learner")
import numpy as np
import factirl_opt as fo
from factirl_opt.learners import adaptive
from _point import setup
P = setup(sys.argv[1:5])
out = {}
for b in map(int, sys.argv[5:]):
    learner = P.learner
    t0 = time.process_time()
    found = adaptive.search_sharing(learner, P.tasks, P.flat.rewards_, search="evidence", candidate_max_iter=b,
                                    transfer_max_iter=20, rule="fewest-within-se")
    ts = time.process_time() - t0
    rows = [(r["n_primitives"], r["residual_penalty"], round(r["score"], 4)) for r in found.rows]
    out[b] = {"chosen": [found.n_primitives, found.residual_penalty], "search_cpu_s": ts, "rows": rows}
    print(b, out[b], flush=True)
    json.dump(out, open(sys.argv[4], "w"), indent=1, default=float)
