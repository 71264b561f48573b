"""The tables of results/transfer/README.md from the records of points.py: ``python results/transfer/table.py [DIR]``.

A point is (benchmark, training tasks, seed, learner); the adaptive learner's rows where it chose
the factorial model (the same k and lambda) are left out (their transfers are the factorial's).
"No worse": the point's mean test deviation at most today's (``none``); "not significantly worse":
a one-sided paired t-test over the point's test tasks (the same tasks and demonstrations) does not
find the variant's mean deviation above today's at 5% (the sharing search's significance rule;
an exact tie counts as not worse); "tasks no worse": the fraction of test tasks whose deviation is
at most today's.
"""
import glob
import json
import sys

import numpy as np
from scipy import stats

DIR = sys.argv[1] if len(sys.argv) > 1 else "results/transfer/points"
BASE = "none"
ALPHA = 0.05  # the one-sided paired test's level
MARGIN = 1.10  # the benchmark's "no worse" (factirl_opt.lab.experiments.claims.SHARING_MARGINS["deviation"])


def not_significantly_worse(dev, base):
    """Whether a one-sided paired t-test does not find ``dev``'s mean above ``base``'s at ``ALPHA``."""
    d = np.asarray(dev) - np.asarray(base)
    if not np.any(d):
        return True
    return stats.ttest_rel(dev, base, alternative="greater").pvalue > ALPHA


def main():
    recs = [json.load(open(f)) for f in sorted(glob.glob(f"{DIR}/*.json"))]
    rows, variants = [], None
    for r in recs:
        fact = r["learners"]["factorial"]
        for name, e in r["learners"].items():
            if name != "factorial" and (e["k"], e["lambda"]) == (fact["k"], fact["lambda"]):
                continue  # the adaptive learner chose the factorial model: the same transfers
            for t in (1, 3):
                v = {k.split("@")[0]: x for k, x in e["variants"].items() if k.endswith(f"@{t}")}
                variants = variants or list(v)
                rows.append(((r["preset"], r["n_tasks"], r["seed"], name, t), e, v))
    print("| variant | demos | points no worse (<= today's mean) | not significantly worse (paired, 5%) | within 10% of today's | mean ratio to today | mean deviation | tasks no worse | max_iter tasks | runs with MaxIterWarning | CPU ratio to today |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for t in (1, 3):
        sel = [(key, e, v) for key, e, v in rows if key[4] == t]
        for name in variants:
            ok = [v[name]["mean"] <= v[BASE]["mean"] + 1e-9 for _, _, v in sel]
            margin = [v[name]["mean"] <= MARGIN * v[BASE]["mean"] for _, _, v in sel]
            paired = [not_significantly_worse(v[name]["deviation"], v[BASE]["deviation"]) for _, _, v in sel]
            ratio = [v[name]["mean"] / v[BASE]["mean"] for _, _, v in sel]
            tasks = np.concatenate([np.asarray(v[name]["deviation"]) <= np.asarray(v[BASE]["deviation"]) + 1e-9
                                    for _, _, v in sel])
            mi = sum(v[name].get("max_iter_tasks", 0) for _, _, v in sel)
            nt = sum(len(v[name]["deviation"]) for _, _, v in sel)
            warn = sum(bool(v[name].get("max_iter_warnings", 0)) for _, _, v in sel)
            cpu = sum(v[name]["cpu"] for _, _, v in sel) / sum(v[BASE]["cpu"] for _, _, v in sel)
            mean = np.mean([v[name]["mean"] for _, _, v in sel])
            print(f"| {name} | {t} | {sum(ok)}/{len(ok)} | {sum(paired)}/{len(ok)} | {sum(margin)}/{len(ok)} | {np.mean(ratio):.3f} | {mean:.3f} | {tasks.mean():.2f} | "
                  f"{mi}/{nt} | {warn}/{len(sel)} | {cpu:.2f} |")
    print()
    print("| point | learner | (k, lambda) | demos | " + " | ".join(variants) + " | scale (1se) |")
    print("|---|---|---|---|" + "---|" * (len(variants) + 1))
    for key, e, v in rows:
        lam = "inf" if e["lambda"] == float("inf") else f"{e['lambda']:g}"
        print(f"| {key[0]} {key[1]} s{key[2]} | {key[3]} | ({e['k']}, {lam}) | {key[4]} | "
              + " | ".join(f"{v[n]['mean']:.3f}" for n in variants) + f" | {e['scale']:g} ({e['scale_1se']:g}) |")


def flat_table(pattern="results/transfer/flat/*.json"):
    """The flat model's transfers (flat_model.py): mean deviation per value of transfer_stol."""
    recs = [json.load(open(f)) for f in sorted(glob.glob(pattern))]
    if not recs:
        return
    names = list(recs[0]["variants"])
    print()
    print("| world | seed | " + " | ".join(f"stol {n}" for n in names) + " |")
    print("|---|---|" + "---|" * len(names))
    for r in recs:
        print(f"| {r['preset']} | {r['seed']} | " + " | ".join(
            f"{r['variants'][n]['mean']:.3f}" + (f" ({r['variants'][n]['max_iter_tasks']} at max_iter)"
                                                 if r['variants'][n]['max_iter_tasks'] else "") for n in names) + " |")
    print()
    print("| stol | worlds x seeds no worse than today's | within 10% | mean ratio to today | runs with MaxIterWarning | CPU ratio to today |")
    print("|---|---|---|---|---|---|")
    for n in names:
        ok = sum(r["variants"][n]["mean"] <= r["variants"]["0"]["mean"] + 1e-9 for r in recs)
        margin = sum(r["variants"][n]["mean"] <= MARGIN * r["variants"]["0"]["mean"] for r in recs)
        ratio = np.mean([r["variants"][n]["mean"] / r["variants"]["0"]["mean"] for r in recs])
        warn = sum(bool(r["variants"][n]["max_iter_warnings"]) for r in recs)
        cpu = sum(r["variants"][n]["cpu"] for r in recs) / sum(r["variants"]["0"]["cpu"] for r in recs)
        print(f"| {n} | {ok}/{len(recs)} | {margin}/{len(recs)} | {ratio:.3f} | {warn}/{len(recs)} | {cpu:.2f} |")


if __name__ == "__main__":
    main()
    flat_table()
