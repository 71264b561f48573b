"""The calibration table of README.md from calibration_seed*.json.

Usage: python results/transfer-prediction/table.py SEED... (the last one printed apart: the held-out draw)
"""
import json
import sys
from pathlib import Path

HERE = Path(__file__).parent


def main(seeds):
    runs = [json.loads((HERE / f"calibration_seed{s}.json").read_text()) for s in seeds]
    tuned, held = runs[:-1], runs[-1]
    print("| posterior | coverage of the 90% bound (seeds " + ", ".join(str(r["seed"]) for r in tuned) +
          f"; held-out {held['seed']}) | Spearman (same) | mean Spearman of the seeds | mean expected regret |")
    print("|---|---|---|---|---|")
    for row in runs[0]["rows"]:
        cov = " / ".join(f"{r['rows'][row]['coverage_90']:.2f}" for r in tuned) + f"; **{held['rows'][row]['coverage_90']:.2f}**"
        rho = " / ".join(f"{r['rows'][row]['spearman']:.2f}" for r in tuned) + f"; **{held['rows'][row]['spearman']:.2f}**"
        mean = sum(r["rows"][row]["spearman"] for r in tuned) / len(tuned)
        er = " / ".join(f"{r['rows'][row]['mean_expected_regret']:.2f}" for r in runs)
        print(f"| {row} | {cov} | {rho} | {mean:.2f} | {er} |")
    print()
    print("mean deviation of the posterior mean: " + " / ".join(f"{r['rows']['conditional']['mean_deviation']:.2f}" for r in runs))
    for key in ("fit_cpu_s", "transfer_cpu_s", "bootstrap8_fit_cpu_s", "folds5_fit_cpu_s"):
        print(key + ": " + " / ".join(f"{r[key]:.1f}" for r in runs))
    for row in runs[0]["rows"]:
        print(f"posterior_cpu_s {row}: " + " / ".join(f"{r['rows'][row]['posterior_cpu_s']:.2f}" for r in runs))


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]])
