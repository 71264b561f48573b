"""The markdown table of the rank_grid20_s*.json records (``rank_routes.py``): python table.py [RANK.json ...]"""
import glob
import json
import os
import sys

here = os.path.dirname(os.path.abspath(__file__))
paths = sys.argv[1:] or sorted(glob.glob(os.path.join(here, "rank_*.json")))


def f(x):
    return "-" if x is None else f"{x:.2f}"


print("| point | seed | route | n | rho route | rho exact, same candidates | route vs exact | chosen (k, lambda) | test dev. | fits |")
print("|---|---|---|---|---|---|---|---|---|---|")
for path in paths:
    d = json.load(open(path))
    for name in ("evidence", "pca", "race", "full"):
        if name not in d["routes"]:
            continue
        r = d["routes"][name]
        print(f"| {d['preset'].removeprefix('sharing-')} {d['n_tasks']} | {d['seed']} | {name} | {r['n']} | {f(r['rho_route'])} | "
              f"{f(r['rho_exact'])} | {f(r['rho_route_exact'])} | ({r['chosen'][0]}, {r['chosen'][1]:g}) | "
              f"{r['test_deviation']:.2f} | {r['candidate_fits']} |")
