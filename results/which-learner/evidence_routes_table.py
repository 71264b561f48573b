"""The table of ``diagnostics/evidence/routes/*.json`` (``routes.py`` records of the ``"evidence"`` and
``"pca"`` routes): ``python results/which-learner/evidence_routes_table.py [FOLDER]`` (default
``routes``; ``routes-walk``: the route with its refinement of k)

Per point and route: the chosen pair, its test deviation (BabyAI too), the cost ratio
((search + final fit) / the factorial fit, CPU time in one process), the search's and the final
fit's CPU seconds, and the factorial learner's test figure in the same process.
"""
import glob
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
print("| point | seed | route | chosen (k, lambda) | test | factorial (k = 5) | ratio | search s | final fit s |")
print("|---|---|---|---|---|---|---|---|---|")
for path in sorted(glob.glob(os.path.join(HERE, "diagnostics", "evidence", (sys.argv[1:] or ["routes"])[0], "routes_*.json"))):
    d = json.load(open(path))
    point = f"{d['preset'].replace('sharing-', '')} {d['n_tasks']}"
    for route, r in d["routes"].items():
        k, lam = r["chosen"]
        print(f"| {point} | {d['seed']} | {route} | ({k}, {lam:g}) | {r['test_deviation']:.2f} | "
              f"{d['factorial']['test_deviation']:.2f} | {r['cost_ratio']:.2f}x | {r['search_cpu_s']:.2f} | "
              f"{r['final_cpu_s']:.2f} |")
