"""The table of ``diagnostics/evidence/routes/*.json`` (``routes.py`` records of the ``"evidence"`` and
``"pca"`` routes), beside the committed verdicts: ``python results/which-learner/evidence_routes_table.py``

Per point and route: the chosen pair, its test deviation (or success rate), the cost ratio
((search + final fit) / the factorial fit, CPU time in one process), the search's and the final
fit's CPU seconds, and whether the chosen pair is no worse than the better of this process's flat
and factorial learners (10% deviation margin; the flat learner's figure is that of the pair (1, 0)
when a route chose it, else missing).
"""
import glob
import json
import os

HERE = os.path.dirname(os.path.abspath(__file__))
print("| point | seed | route | chosen (k, lambda) | test | factorial (k = 5) | ratio | search s | final fit s |")
print("|---|---|---|---|---|---|---|---|---|")
for path in sorted(glob.glob(os.path.join(HERE, "diagnostics", "evidence", "routes", "*.json"))):
    d = json.load(open(path))
    point = f"{d['preset'].replace('sharing-', '')} {d['n_tasks']}"
    for route, r in d["routes"].items():
        k, lam = r["chosen"]
        print(f"| {point} | {d['seed']} | {route} | ({k}, {lam:g}) | {r['test_deviation']:.2f} | "
              f"{d['factorial']['test_deviation']:.2f} | {r['cost_ratio']:.2f}x | {r['search_cpu_s']:.2f} | "
              f"{r['final_cpu_s']:.2f} |")
