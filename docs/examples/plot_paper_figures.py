"""
The paper's figures 1 and 2, from the committed reproduction
=============================================================

Mangin & Oudeyer (2014) plot the deviation of each learner (lower is better) against the number
of demonstrations per training task (figure 1) and against the number of training tasks
(figure 2), on training tasks and on new tasks learnt from one demonstration. The paper-scale
run is committed in the repository's ``results/`` (``factirl-opt reproduce --preset paper
--jobs 2``, about 19 minutes); this script only reads its ``summary.csv`` and draws both
figures side by side. ``factirl-opt plot results`` draws the same figures from the command line.
"""

import csv
import pathlib

import matplotlib.pyplot as plt


def results_dir():
    """The repository's results/ (this script sits in docs/examples/)."""
    here = pathlib.Path(__file__).resolve().parent if "__file__" in globals() else pathlib.Path.cwd()
    for base in (here, *here.parents):
        if (base / "results" / "summary.csv").is_file():
            return base / "results"
    raise FileNotFoundError("results/summary.csv not found: run this script from a clone of the repository")


rows = list(csv.DictReader(open(results_dir() / "summary.csv")))
learners = ["flat", "factorial", "flat, PCA features", "flat, ground truth"]

fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharey="row")
for col, (sweep, fixed, fixed_value, label) in enumerate(
        [("demos_per_task", "n_tasks", "100", "demonstrations per training task"),
         ("n_tasks", "demos_per_task", "10", "training tasks")]):
    for row, split in enumerate(["train", "test"]):
        ax = axes[row, col]
        for learner in learners:
            points = sorted((int(r[sweep]), float(r["deviation_mean"]), float(r["deviation_std"]))
                            for r in rows if r["split"] == split and r["learner"] == learner
                            and r[fixed] == fixed_value and r["h_solver"] == "armijo")
            if points:
                x, y, s = zip(*points)
                ax.errorbar(x, y, yerr=s, marker="o", capsize=3, label=learner)
        ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_title(f"figure {col + 1}: {split} tasks")
axes[0, 0].set_ylabel("deviation (lower is better)")
axes[1, 0].set_ylabel("deviation, one-demonstration transfer")
axes[0, 0].legend(fontsize=8)
fig.tight_layout()
plt.show()
