"""The markdown table of the rank_grid20_s*.json records (``rank_routes.py``): python table.py [RANK.json ...]"""
import glob
import json
import os
import sys

here = os.path.dirname(os.path.abspath(__file__))
paths = sys.argv[1:] or sorted(glob.glob(os.path.join(here, "rank_*.json")))


def routes_tables(d):
    """Each route's validation table, from the routes records the rank record was made from."""
    tables = {}
    for path in d["routes_files"]:
        p = path if os.path.exists(path) else os.path.join(here, "..", "..", "..", "..", path)
        tables.update({name: v["table"] for name, v in json.load(open(p))["routes"].items()})
    return tables


def f(x):
    return "-" if x is None else f"{x:.2f}"


print("| point | seed | route | n | rho route | rho exact, same candidates | route vs exact | chosen (k, lambda) | test dev. "
      "| best-scored (k, lambda) | test dev. | fits |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for path in paths:
    d = json.load(open(path))
    for name in ("evidence", "pca", "race", "full"):
        if name not in d["routes"]:
            continue
        r = d["routes"][name]
        table = d["race_table"] if name == "race" else routes_tables(d)[name]
        most = max(len(row["fold_scores"]) for row in table)
        scored = [row for row in table if len(row["fold_scores"]) == most and most > 0]
        lead = min(scored, key=lambda row: row["score"]) if scored else None
        lead_pair = (lead["n_primitives"], lead["residual_penalty"]) if lead else tuple(r["chosen"])
        lead_dev = d["test_deviation"][f"{lead_pair[0]},{float(lead_pair[1])}"]
        print(f"| {d['preset'].removeprefix('sharing-')} {d['n_tasks']} | {d['seed']} | {name} | {r['n']} | {f(r['rho_route'])} | "
              f"{f(r['rho_exact'])} | {f(r['rho_route_exact'])} | ({r['chosen'][0]}, {r['chosen'][1]:g}) | "
              f"{r['test_deviation']:.2f} | ({lead_pair[0]}, {lead_pair[1]:g}) | {lead_dev:.2f} | {r['candidate_fits']} |")
