"""The README's table from the `bench gpi` JSON files: python results/gpi/table.py FILE.json ...

Library parts: P primitives, N negatives, T tasks, O other-tasks."""

import json
import sys

PARTS = {"primitives": "P", "negatives": "N", "tasks": "T", "other-tasks": "O"}
COLUMNS = ("world", "seed", "S", "maps", "library", "L", "fit CPU s", "library CPU s", "plan CPU s", "GPI CPU s", "GPI+1 CPU s",
           "GPI / plan CPU", "GPI+1 / plan CPU", "learnt loss GPI", "learnt loss GPI+1", "true loss plan",
           "true loss GPI", "true loss GPI+1", "GPI / plan true loss", "GPI+1 / plan true loss", "theorem violations")


def rows(paths):
    for path in paths:
        with open(path) as f:
            result = json.load(f)
        for world, seeds in result["worlds"].items():
            for seed, r in seeds.items():
                parts = "+".join(PARTS[p] for p in r["library"])
                yield (world, seed, r["n_states"], r["n_maps"], parts, "/".join(sorted({str(x) for x in r["library_size"]})),
                       f"{r['fit_cpu_s']:.1f}", f"{r['library_cpu_s']:.2f}", f"{r['plan_cpu_s']:.2f}",
                       f"{r['gpi_cpu_s']:.3f}", f"{r['gpi1_cpu_s']:.2f}", f"1/{1 / r['cpu_gpi_over_plan']:.0f}",
                       f"{r['cpu_gpi1_over_plan']:.2f}", f"{r['learnt_loss']['gpi']:.3f}", f"{r['learnt_loss']['gpi1']:.3f}",
                       f"{r['true_loss']['plan']:.3f}", f"{r['true_loss']['gpi']:.3f}", f"{r['true_loss']['gpi1']:.3f}",
                       f"{r['true_loss_gpi_over_plan']:.3f}", f"{r['true_loss_gpi1_over_plan']:.3f}",
                       r["theorem_violations"])


def main(paths):
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for row in rows(paths):
        print("| " + " | ".join(map(str, row)) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
