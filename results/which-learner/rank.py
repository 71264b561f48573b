"""Rank agreement of a route's held-out scores with the candidates' test deviations on one point:
python rank.py PRESET N SEED ROUTES.json OUT.json

ROUTES.json is a record of ``routes.py`` on the same point (its tables); every candidate of the first
route's table is fitted on all the point's training tasks from the flat start and transferred to
its test tasks from one demonstration (``_point.test_deviation``); prints and records each route's
Spearman correlation between its candidates' mean held-out scores and their test deviations (over
the candidates the route scored on every fold, and over all)."""
import json
import os
import sys

from scipy.stats import spearmanr

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _point import setup, test_deviation  # noqa: E402

P = setup(sys.argv[1:4] + [sys.argv[5]])
routes = json.load(open(sys.argv[4]))["routes"]
pairs = sorted({(r["n_primitives"], r["residual_penalty"]) for v in routes.values() for r in v["table"]})
out = {"test_deviation": {}, "spearman": {}}
for k, lam in pairs:
    out["test_deviation"][f"{k},{lam}"] = test_deviation(P, k, lam)
    print(k, lam, out["test_deviation"][f"{k},{lam}"], flush=True)
for name, v in routes.items():
    most = max(len(r["fold_scores"]) for r in v["table"])
    for which, rows in (("complete", [r for r in v["table"] if len(r["fold_scores"]) == most]), ("all", v["table"])):
        scores = [r["score"] for r in rows]
        devs = [out["test_deviation"][f"{r['n_primitives']},{r['residual_penalty']}"] for r in rows]
        out["spearman"][f"{name}/{which}"] = {"rho": float(spearmanr(scores, devs)[0]) if len(rows) > 2 else None,
                                             "n": len(rows)}
    print(name, out["spearman"], flush=True)
with open(P.out_path, "w") as f:
    json.dump(out, f, indent=1)
