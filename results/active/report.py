"""Plot and README tables of ``bench active`` (results/active/*.json).

Usage: python results/active/report.py   (writes results/active/active.png, prints the tables)
"""

import json
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = pathlib.Path(__file__).parent
FILES = {"grid": "grid.json", "objectworld-per-task-quick": "objectworld-per-task-quick.json"}
COLOURS = {"requested": "C3", "requested-value": "C1", "random": "C0", "entropy": "C2", "requested-regret": "C4",
           "requested-value-skip": "C5"}


def load():
    worlds = {}
    for name, file in FILES.items():
        path = HERE / file
        if path.exists() and path.stat().st_size:
            worlds[name] = json.loads(path.read_text())["worlds"][name]
    return worlds


def curves(seeds, strategy, key="deviation"):
    return np.array([row["strategies"][strategy][key] for row in seeds.values()])


def demos_to_reach(curve, target):
    hit = np.flatnonzero(curve <= target + 1e-12)
    return int(hit[0]) + 1 if hit.size else None


def main():
    worlds = load()
    fig, axes = plt.subplots(1, len(worlds), figsize=(6 * len(worlds), 4.2), squeeze=False)
    for ax, (name, seeds) in zip(axes[0], worlds.items()):
        strategies = list(next(iter(seeds.values()))["strategies"])
        random8 = curves(seeds, "random").mean(axis=0)[-1]
        print(f"\n### {name} ({len(seeds)} seeds, {next(iter(seeds.values()))['n_test']} test tasks each)\n")
        n = curves(seeds, strategies[0]).shape[1]
        print("| starts | " + " | ".join(str(i) for i in range(1, n + 1)) + " | demos to reach random's "
              f"{n}-demo deviation |")
        print("|---" * (n + 2) + "|")
        for st in strategies:
            c = curves(seeds, st)
            mean = c.mean(axis=0)
            x = np.arange(1, n + 1)
            for row in c:
                ax.plot(x, row, color=COLOURS.get(st, "k"), alpha=0.2, linewidth=0.8)
            ax.plot(x, mean, color=COLOURS.get(st, "k"), marker="o", label=st)
            reach = demos_to_reach(mean, random8)
            print(f"| {st} | " + " | ".join(f"{v:.2f}" for v in mean) + f" | {reach if reach else '> ' + str(n)} |")
        for st in strategies:
            mean = curves(seeds, st, "map_deviation").mean(axis=0)
            print(f"| {st} (posterior mean) | " + " | ".join(f"{v:.2f}" for v in mean) + " | |")
        ax.set_title(f"{name}: mean deviation over test tasks and seeds")
        ax.set_xlabel("demonstrations per test task")
        ax.set_ylabel("deviation (transferred rewards)")
        ax.legend()
        costs = [row["request_cost"] for row in seeds.values()]
        print("\nrequest cost / transfer cost per seed (ratio of sums; median and max per task): "
              + "; ".join(f"{c['request_over_transfer']:.2f} ({c['median_task_ratio']:.2f}, {c['max_task_ratio']:.2f})"
                          for c in costs))
        cal = [row["calibration"] for row in seeds.values() if "calibration" in row]
        if cal:
            print("\n| seed | coverage of the 90% bound | Spearman(expected regret, deviation) | "
                  "mean expected regret | mean deviation (posterior mean) | mean deviation (transferred) |")
            print("|---|---|---|---|---|---|")
            for seed, c in zip(seeds, cal):
                print(f"| {seed} | {c['coverage_90']:.2f} | {c['spearman']:.2f} | {c['mean_expected_regret']:.2f} | "
                      f"{c['mean_deviation_map']:.2f} | {c['mean_deviation_transferred']:.2f} |")
            print(f"| mean | {np.mean([c['coverage_90'] for c in cal]):.2f} | {np.mean([c['spearman'] for c in cal]):.2f} "
                  f"| | | |")
    fig.tight_layout()
    fig.savefig(HERE / "active.png", dpi=110)


if __name__ == "__main__":
    main()
