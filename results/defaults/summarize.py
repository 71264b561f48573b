"""Tables of the defaults study from the JSON lines of ``defaults_study.py``.

    python results/defaults/summarize.py results/defaults/walled_maps_seed0.jsonl [--reference e87d706:defaults]

One markdown table per file: a row per (label, candidate, objective) with the fastest CPU time of
its fits (all of them in brackets), the ratio to the reference row of the same objective (by
default this code's ``defaults``), evaluations, status, train deviation and its ratio, the mean
test deviation (or BabyAI's success rate) and its ratio, the paired difference of the test
deviations with the reference (mean +- standard error, and on how many test tasks it is no
higher), the transfer's CPU time and its ``MaxIterWarning`` count.
"""

import argparse
import json

import numpy as np


def load(path):
    rows = {}
    with open(path) as f:
        for line in f:
            e = json.loads(line)
            key = (e["label"], e["candidate"], e["objective"])
            row = rows.setdefault(key, dict(e, cpus=[]))
            row["cpus"].append(e["cpu_s"])
            if "mean_test_deviation" in e:
                row.update({k: v for k, v in e.items() if k.startswith(("mean_test", "test_", "transfer_", "success"))})
    return rows


def table(rows, reference):
    ref_label, ref_name = reference.split(":")
    out = ["| code | setting | objective | CPU s (all) | CPU ratio | evaluations | status | train dev. | ratio "
           "| test dev. | ratio | paired test diff. (no higher on) | transfer CPU s | MaxIterWarning |",
           "|" + "---|" * 14]
    for (label, name, objective), r in sorted(rows.items(), key=lambda kv: (kv[0][2], kv[0][0] != ref_label,
                                                                            min(kv[1]["cpus"]))):
        ref = rows.get((ref_label, ref_name, objective))
        cpu = min(r["cpus"])
        ratio = cpu / min(ref["cpus"]) if ref else float("nan")
        tr = r["mean_train_deviation"] / ref["mean_train_deviation"] if ref else float("nan")
        test, tratio, paired = "", "", ""
        if "mean_test_deviation" in r:
            test = f"{r['mean_test_deviation']:.3f}"
            if "success_rate" in r:
                test += f" ({r['success_rate']:.2f} success)"
            if ref and "mean_test_deviation" in ref:
                tratio = f"{r['mean_test_deviation'] / ref['mean_test_deviation']:.3f}"
                d = np.subtract(r["test_deviations"], ref["test_deviations"])
                paired = f"{d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(len(d)):.3f} ({int(np.sum(d <= 1e-9))}/{len(d)})"
        warn = r.get("transfer_warnings", {}).get("MaxIterWarning", 0) if "transfer_warnings" in r else ""
        out.append(f"| {label} | {name} | {objective} | {cpu:.1f} ({', '.join(f'{c:.1f}' for c in r['cpus'])}) | "
                   f"{ratio:.2f} | {r['n_evaluations']} | {r['status']} | {r['mean_train_deviation']:.3f} | {tr:.3f} | "
                   f"{test} | {tratio} | {paired} | {r.get('transfer_cpu_s', '')} | {warn} |")
    return "\n".join(out)


def acceptance(paths, reference):
    """The acceptance criteria per setting and objective over the files (one per seed): CPU, train
    and test deviation as ratios to the reference row of the same file, per seed, and the test
    deviations' paired difference pooled over the seeds' test tasks."""
    ref_label, ref_name = reference.split(":")
    per = {}
    for path in paths:
        rows = load(path)
        for (label, name, objective), r in rows.items():
            ref = rows.get((ref_label, ref_name, objective))
            if ref is None or (label, name) == (ref_label, ref_name) or "mean_test_deviation" not in r:
                continue
            per.setdefault((label, name, objective), []).append(
                (r["seed"], min(r["cpus"]) / min(ref["cpus"]), r["mean_train_deviation"] / ref["mean_train_deviation"],
                 r["mean_test_deviation"] / ref["mean_test_deviation"], np.subtract(r["test_deviations"], ref["test_deviations"])))
    out = ["| code | setting | objective | seeds | CPU ratio per seed | train dev. ratio per seed | test dev. ratio per seed "
           "| pooled paired test diff. (no higher on) |", "|" + "---|" * 8]
    for (label, name, objective), v in sorted(per.items(), key=lambda kv: (kv[0][2], kv[0][1])):
        v.sort(key=lambda t: t[0])
        d = np.concatenate([t[4] for t in v])
        out.append(f"| {label} | {name} | {objective} | {', '.join(str(t[0]) for t in v)} | "
                   + " | ".join(", ".join(f"{t[i]:.2f}" for t in v) for i in (1, 2, 3))
                   + f" | {d.mean():+.3f} +- {d.std(ddof=1) / np.sqrt(len(d)):.3f} ({int(np.sum(d <= 1e-9))}/{len(d)}) |")
    return "\n".join(out)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("files", nargs="+")
    parser.add_argument("--reference", default="HEAD:defaults", help="LABEL:CANDIDATE of the ratios' denominator")
    parser.add_argument("--acceptance", action="store_true", help="one table over the files (seeds) instead")
    args = parser.parse_args()
    if args.acceptance:
        print(acceptance(args.files, args.reference))
        return
    for path in args.files:
        print(f"### {path}\n")
        print(table(load(path), args.reference))
        print()


if __name__ == "__main__":
    main()
