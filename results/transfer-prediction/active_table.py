"""The active-request tables of README.md from active_WORLD_seedSEED.json.

Usage: python results/transfer-prediction/active_table.py WORLD SEED... (the last one: the held-out draw)
"""
import json
import sys
from pathlib import Path

HERE = Path(__file__).parent


def main(world, seeds):
    rows = {s: json.loads((HERE / f"active_{world}_seed{s}.json").read_text())["worlds"][world][str(s)] for s in seeds}
    tuned, held = seeds[:-1], seeds[-1]
    strategies = list(rows[seeds[0]]["strategies"])
    n = len(rows[seeds[0]]["strategies"][strategies[0]]["deviation"])
    print(f"#### {world}: mean of seeds {', '.join(map(str, tuned))}")
    print("| starts | " + " | ".join(str(i + 1) for i in range(n)) + " |")
    print("|---|" + "---|" * n)
    for st in strategies:
        curve = [sum(rows[s]["strategies"][st]["deviation"][i] for s in tuned) / len(tuned) for i in range(n)]
        print(f"| {st} | " + " | ".join(f"{c:.2f}" for c in curve) + " |")
    print()
    print("| seed | random at 8 | " + " | ".join(f"{st} at 5" for st in strategies if st != "random") + " |")
    print("|---|---|" + "---|" * (len(strategies) - 1))
    for s in seeds:
        r8 = rows[s]["strategies"]["random"]["deviation"][7]
        cells = []
        for st in strategies:
            if st == "random":
                continue
            v = rows[s]["strategies"][st]["deviation"][4]
            cells.append(f"{v:.2f} ({'no worse' if v <= r8 else 'worse'})")
        print(f"| {s}{' (held out)' if s == held else ''} | {r8:.2f} | " + " | ".join(cells) + " |")
    print()
    for s in seeds:
        c = rows[s]["request_cost"]
        print(f"seed {s}: fit {rows[s]['fit_cpu_s']:.1f} s CPU; one request / one transfer {c['request_over_transfer']:.2f} "
              f"(median task {c['median_task_ratio']:.2f}, max {c['max_task_ratio']:.2f})")


if __name__ == "__main__":
    main(sys.argv[1], [int(a) for a in sys.argv[2:]])
