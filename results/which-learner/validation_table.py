"""Re-run one which-learner point and record the adaptive learner's validation table and paired t statistics."""
import sys, json, warnings
import numpy as np
from scipy.stats import t as t_dist
import factirl_opt.learners.factirl as fmod
from factirl_opt.lab.experiments import PRESETS
from factirl_opt.lab.experiments.runner import RunSpec, run_one
warnings.simplefilter("ignore")
tables = []
orig = fmod.choose_sharing
def rec(*a, **k):
    out = orig(*a, **k); tables.append(out[2]); return out
fmod.choose_sharing = rec
preset = PRESETS[sys.argv[1]]; n = int(sys.argv[2]); seed = int(sys.argv[3])
record = run_one(preset, RunSpec(n, preset.default_demos, seed))
table = tables[0]
flat = next(r for r in table if r["residual_penalty"] == 0.0)
out = {"rows": record["rows"], "table": table, "paired": []}
for r in table:
    if len(r["task_scores"]) != len(flat["task_scores"]) or r is flat:
        continue
    g = np.array(flat["task_scores"]) - np.array(r["task_scores"])
    tstat = g.mean() / (g.std(ddof=1) / np.sqrt(g.size))
    out["paired"].append({"k": r["n_primitives"], "lam": r["residual_penalty"], "gain": g.mean(), "t": tstat,
                          "p": float(t_dist.sf(tstat, g.size - 1)), "n": g.size})
    print(out["paired"][-1], flush=True)
for row in record["rows"]:
    if row["split"] == "test":
        print(row["learner"], row["deviation"], row.get("success_rate"), row.get("n_primitives"), row.get("residual_penalty"))
json.dump(out, open(sys.argv[4], "w"), default=float)
