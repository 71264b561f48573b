"""One which-learner point's search, its validation table and the paired t statistics of each candidate
against the flat model, with the chosen pair's test deviation: python validation_table.py PRESET N SEED OUT.json

The search is the adaptive learner's of the runner's line-up (``_point.setup``: the same flat start
and rng), run through the public ``adaptive.search_sharing`` (this script used to wrap the library's
``choose_sharing`` by assigning into ``factirl_opt.learners.factirl``)."""
import json
import os
import sys

import numpy as np
from scipy.stats import t as t_dist

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from factirl_opt.learners import adaptive  # noqa: E402
from _point import setup, test_deviation  # noqa: E402

P = setup(sys.argv[1:5])
found = adaptive.search_sharing(P.learner, P.tasks, P.flat.rewards_)
table = found.rows
flat = next(r for r in table if r["residual_penalty"] == 0.0)
out = {"chosen": [found.n_primitives, found.residual_penalty], "table": table, "paired": []}
for r in table:
    if len(r["task_scores"]) != len(flat["task_scores"]) or r is flat:
        continue
    g = np.array(flat["task_scores"]) - np.array(r["task_scores"])
    tstat = g.mean() / (g.std(ddof=1) / np.sqrt(g.size))
    out["paired"].append({"k": r["n_primitives"], "lam": r["residual_penalty"], "gain": g.mean(), "t": tstat,
                          "p": float(t_dist.sf(tstat, g.size - 1)), "n": g.size})
    print(out["paired"][-1], flush=True)
out["test_deviation"] = test_deviation(P, found.n_primitives, found.residual_penalty)
print("chosen", out["chosen"], "test deviation", out["test_deviation"])
json.dump(out, open(P.out_path, "w"), default=float)
