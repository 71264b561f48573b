"""The tables of "The flat start, after the switch" (results/defaults/README.md) from the JSON lines of
``run_switch.sh`` and the other worlds' runs (``*_switch_seed*.jsonl``):

    python results/defaults/switch_table.py
"""
import glob
import json
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
NAMES = {"defaults": "L-BFGS start (the switch's first defaults)", "armijo-stol-start": "Armijo start + saturation (the defaults)",
         "armijo-start": "Armijo start, no saturation", "joint-armijo-start": "Armijo start, no saturation"}


def rows(pattern):
    return [json.loads(line) for path in sorted(glob.glob(os.path.join(HERE, pattern))) for line in open(path)]


def paired(a, b):
    d = np.asarray(a["test_deviations"]) - np.asarray(b["test_deviations"])
    return f"{d.mean():+.2f} +- {d.std(ddof=1) / np.sqrt(d.size):.2f}"


print("| setting | objective | seed | CPU ratio | train dev. ratio | test dev. ratio | paired test diff. |")
print("|---|---|---|---|---|---|---|")
walled = rows("walled_maps_switch_seed*.jsonl")
ref = {(r["seed"], r["objective"]): r for r in walled if r["label"] == "e87d706"}
for r in sorted((r for r in walled if r["label"] != "e87d706"), key=lambda r: (r["candidate"], r["objective"], r["seed"])):
    e = ref[r["seed"], r["objective"]]
    print(f"| {NAMES[r['candidate']]} | {r['objective']} | {r['seed']} | {r['cpu_s'] / e['cpu_s']:.2f} | "
          f"{r['mean_train_deviation'] / e['mean_train_deviation']:.2f} | {r['mean_test_deviation'] / e['mean_test_deviation']:.2f} | "
          f"{paired(r, e)} |")
print()
print("| world (seed 0) | setting | objective | CPU s | train dev. | test dev. (success) | paired test diff. vs L-BFGS start |")
print("|---|---|---|---|---|---|---|")
for world in ("per_task_30", "objectworld_20", "grid_20x10", "babyai_30"):
    rs = rows(f"{world}_switch_seed0.jsonl")
    base = {r["objective"]: r for r in rs if r["candidate"] == "defaults"}
    for r in sorted(rs, key=lambda r: (r["objective"], r["candidate"] != "defaults", r["candidate"])):
        test = f"{r['mean_test_deviation']:.2f}" + (f" ({r['success_rate']:.2f})" if "success_rate" in r else "")
        diff = "" if r["candidate"] == "defaults" else paired(r, base[r["objective"]])
        print(f"| {world} | {NAMES[r['candidate']]} | {r['objective']} | {r['cpu_s']:.1f} | {r['mean_train_deviation']:.3f} | "
              f"{test} | {diff} |")
