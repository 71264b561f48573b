"""The table of README §1b from bayes_ceiling.py's JSON files.

Usage: python results/transfer-prediction/ceiling_table.py [SUFFIX]   (SUFFIX: "" or "_test100")

Rows: the posterior; columns: Spearman(expected regret, true deviation) and coverage of the 90%
bound on seeds 0, 1, 2 and the held-out draw 1000, the mean Spearman of seeds 0-2, and for
``fo.learners.importance_posterior`` its CPU in transfers of the same tasks and its median effective
sample size.
"""

import json
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
SEEDS = (0, 1, 2, 1000)


def rows(runs):
    yield "Laplace (`transfer_posterior_`, conditional)", [r["library_conditional"] for r in runs], None
    for j, imp in enumerate(runs[0]["library_importance"]):
        entries = [r["library_importance"][j] for r in runs]
        yield f"`importance_posterior`, {imp['n_particles']:,} draws", entries, entries
    yield "learnt world, the greedy expert's likelihood (40,000 draws kept or not)", [r["learnt_world_greedy_expert"] for r in runs], None
    yield "true world, a Boltzmann expert at the model's beta", [r["true_world_boltzmann_expert"] for r in runs], None
    yield "exact posterior of the generating world", [r["exact_posterior"] for r in runs], None
    yield "oracle: knows the direction of w", [r["oracle_knows_direction"] for r in runs], None
    yield "oracle: knows the norm of w", [r["oracle_knows_norm"] for r in runs], None


def main(suffix=""):
    runs = [json.loads((HERE / f"bayes_ceiling_seed{s}{suffix}.json").read_text()) for s in SEEDS]
    print("| posterior | Spearman (0 / 1 / 2; **1000**) | mean of 0-2 | coverage of the 90% bound (0 / 1 / 2; **1000**) "
          "| CPU in transfers | median effective draws |")
    print("|---|---|---|---|---|---|")
    for name, entries, imp in rows(runs):
        rho = [e["spearman"] for e in entries]
        cov = [e.get("coverage_90") for e in entries]
        cov_text = "-" if cov[0] is None else " / ".join(f"{c:.2f}" for c in cov[:3]) + f"; **{cov[3]:.2f}**"
        cost = "-" if imp is None else f"{min(e['cpu_in_transfers'] for e in imp):.0f}-{max(e['cpu_in_transfers'] for e in imp):.0f}"
        ess = "-" if imp is None else " / ".join(f"{e['median_ess']:.0f}" for e in imp)
        print(f"| {name} | {' / '.join(f'{r:.2f}' for r in rho[:3])}; **{rho[3]:.2f}** | {sum(rho[:3]) / 3:.2f} | "
              f"{cov_text} | {cost} | {ess} |")
    acc = [r["accepted_directions"] for r in runs]
    print()
    print("accepted directions (min / median per seed): " + "; ".join(f"{a['min']} / {a['median']:.0f}" for a in acc))
    print("own direction accepted: " + " ".join(f"{r['own_direction_accepted']}/{r['n_test']}" for r in runs))
    print("largest error of the deviation formula: " + f"{max(r['deviation_formula_max_error'] for r in runs):.1e}")
    print("mean deviation / mean exact expected regret / mean importance expected regret (largest n): " + "; ".join(
        f"{r['mean_deviation']:.2f} / {r['mean_exact_expected_regret']:.2f} / {r['library_importance'][-1]['mean_expected_regret']:.2f}"
        for r in runs))


if __name__ == "__main__":
    main(*sys.argv[1:])
