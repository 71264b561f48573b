"""The which-learner verdicts and CPU-time cost of one search route, per (point, seed), from the run
records of ``factirl-opt bench which-learner --route NAME --out DIR``: python route_table.py DIR [DIR ...]

Per pair: the test score of flat, factorial (the preset's k) and the adaptive learner with its
chosen (k, lambda); *no worse* within 10% of the better deviation or 0.05 of the better success
rate (the benchmark's margins); and the cost ratio, the adaptive training fit's CPU time (search
and final fit, ``fit_cpu_time`` of the records) over the factorial fit's, both from the same flat
start. Then the count of pairs no worse, and the median and maximum ratio, also with the flat
start (the flat row's training fit) added on both sides, as fits from scratch pay it.
"""
import glob
import json
import statistics
import sys

MARGINS = {"deviation": 0.10, "success_rate": 0.05}


def pairs(out):
    for path in sorted(glob.glob(f"{out}/*/runs/*.json")):
        rec = json.load(open(path))
        cpu = {t["learner"].split(",")[0]: t["fit_cpu_time"] for t in rec["timings"] if t["split"] == "train"}
        test = [r for r in rec["rows"] if r["split"] == "test"]
        column = "success_rate" if "success_rate" in test[0] else "deviation"
        score = {r["learner"].split(",")[0]: r[column] for r in test}
        chosen = next((r["n_primitives"], r["residual_penalty"]) for r in rec["rows"] if "n_primitives" in r)
        if column == "deviation":
            ok = score["adaptive"] <= (1 + MARGINS[column]) * min(score["flat"], score["factorial"])
        else:
            ok = score["adaptive"] >= max(score["flat"], score["factorial"]) - MARGINS[column]
        yield dict(preset=rec["preset"]["name"], n_tasks=rec["spec"]["n_tasks"], seed=rec["spec"]["seed"], column=column,
                   score=score, chosen=chosen, no_worse=ok, cpu=cpu, ratio=cpu["adaptive"] / cpu["factorial"])


def main(outs):
    print("| benchmark | tasks | seed | score | flat | factorial | adaptive (k, lambda) | no worse | CPU s factorial | CPU s adaptive | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rows = [p for out in outs for p in pairs(out)]
    for p in rows:
        k, lam = p["chosen"]
        s = p["score"]
        print(f"| {p['preset']} | {p['n_tasks']} | {p['seed']} | {p['column']} | {s['flat']:.3f} | {s['factorial']:.3f} | "
              f"{s['adaptive']:.3f} ({k}, {'inf' if lam == float('inf') else f'{lam:g}'}) | {'yes' if p['no_worse'] else '**no**'} | "
              f"{p['cpu']['factorial']:.2f} | {p['cpu']['adaptive']:.2f} | {p['ratio']:.1f}x |")
    ratios = [p["ratio"] for p in rows]
    print(f"\nno worse on {sum(p['no_worse'] for p in rows)} of {len(rows)} pairs; CPU-time ratio median "
          f"{statistics.median(ratios):.2f}x, max {max(ratios):.1f}x")
    # what a user's fits from scratch pay: the flat start (the flat row's training fit) on both sides
    whole = [(p["cpu"]["flat"] + p["cpu"]["adaptive"]) / (p["cpu"]["flat"] + p["cpu"]["factorial"]) for p in rows]
    print(f"with the flat start on both sides: median {statistics.median(whole):.2f}x, max {max(whole):.1f}x")


if __name__ == "__main__":
    main(sys.argv[1:])
