"""The markdown tables of the scores_*.json records (``scores.py``): python table.py [SCORES.json ...]

Per record: Spearman's rho between each score's candidate means and the candidates' test deviations over every
candidate (the flat model included: likelihood, deviation, oracle) and over the sharing candidates (lambda > 0,
where the posterior's predicted regret is defined), the candidate each score ranks first with its test deviation,
the CPU cost of the deviation (and of the predicted regret) relative to the likelihood's, and the rho within lambda = inf
and within lambda = 1 (choosing k).
"""
import glob
import json
import os
import sys

here = os.path.dirname(os.path.abspath(__file__))
paths = sys.argv[1:] or sorted(glob.glob(os.path.join(here, "scores_*.json")))
records = [json.load(open(p)) for p in paths]


def f(x):
    return "-" if x is None else f"{x:.2f}"


def point(d):
    post = "marginal, B = %d" % d["n_dictionaries"] if d.get("n_dictionaries") else "conditional"
    return f"{d['preset'].removeprefix('sharing-')} {d['n_tasks']} | {d['seed']} | {post}"


print("| point | seed | posterior | n | rho likelihood | rho deviation | rho oracle | n sharing | rho likelihood "
      "| rho deviation | rho predicted regret | rho oracle |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for d in records:
    a, s = d["rho"]["all"], d["rho"]["sharing"]
    print(f"| {point(d)} | {d['n']['all']} | {f(a['likelihood'])} | {f(a['deviation'])} | {f(a['oracle'])} | "
          f"{d['n']['sharing']} | {f(s['likelihood'])} | {f(s['deviation'])} | {f(s['predicted'])} | {f(s['oracle'])} |")
print()
print("| point | seed | posterior | lowest likelihood | test dev. | lowest deviation | test dev. | lowest predicted regret "
      "| test dev. | best test dev. |")
print("|---|---|---|---|---|---|---|---|---|---|")
for d in records:
    low = d["lowest_mean"]

    def c(s):
        k, lam = low[s]["candidate"].split(",")
        return f"({k}, {float(lam):g}) | {low[s]['test_deviation']:.2f}"
    best = min(d["test_deviation"].items(), key=lambda kv: kv[1])
    k, lam = best[0].split(",")
    print(f"| {point(d)} | {c('likelihood')} | {c('deviation')} | {c('predicted')} | ({k}, {float(lam):g}): {best[1]:.2f} |")
print()
print("| point | seed | posterior | CPU s: fits | transfers | likelihood | deviation | reference | predicted regret "
      "| deviation / likelihood: score | with transfers | search | predicted / likelihood: score | with transfers |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for d in records:
    c, r, p = d["cpu_s"], d["cost_ratio_deviation_to_likelihood"], d["cost_ratio_predicted_to_likelihood"]
    print(f"| {point(d)} | {c['fit']:.1f} | {c['transfer']:.2f} | {c['likelihood']:.2f} | {c['deviation']:.2f} | "
          f"{c['reference']:.2f} | {c['predicted']:.2f} | {r['score']:.2f} | {r['transfers_and_score']:.2f} | "
          f"{r['search']:.3f} | {p['score']:.1f} | {p['transfers_and_score']:.2f} |")
print()
print("| point | seed | posterior | lambda | n | rho likelihood | rho deviation | rho predicted regret | rho oracle |")
print("|---|---|---|---|---|---|---|---|---|")
for d in records:
    for lam in ("inf", "1"):
        r = d["rho"][f"lambda={lam}"]
        n = sum(1 for c in d["candidates"] if float(c.split(",")[1]) == float(lam))
        print(f"| {point(d)} | {lam} | {n} | {f(r['likelihood'])} | {f(r['deviation'])} | {f(r['predicted'])} | {f(r['oracle'])} |")
