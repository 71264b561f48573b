"""
The paper's figures 1 and 2, from the committed reproduction
=============================================================

Mangin & Oudeyer (2014) plot the deviation of each learner (lower is better) on the training
tasks (figure 1) and on new tasks learnt from one demonstration each (figure 2), against the
number of demonstrations per training task and against the number of training tasks. The
paper-scale run is committed in the repository's ``results/`` (``factirl-opt reproduce --preset
paper --jobs 2``; its time is on the site's results page); this script only reads its
``summary.csv`` and draws both figures. ``factirl-opt plot results`` draws the same figures from the command line.
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


with open(results_dir() / "summary.csv", newline="") as f:
    rows = list(csv.DictReader(f))
learners = ["flat", "factorial", "flat, PCA features", "flat, ground truth"]

fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharey="row")
for col, (sweep, fixed, fixed_value, label) in enumerate(
        [("demos_per_task", "n_tasks", "100", "demonstrations per training task (100 tasks)"),
         ("n_tasks", "demos_per_task", "10", "training tasks (10 demonstrations each)")]):
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
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.set_title(f"figure {row + 1}: {'training tasks' if split == 'train' else 'new tasks, one demonstration'}")
axes[0, 0].set_ylabel("deviation (lower is better)")
axes[1, 0].set_ylabel("deviation (lower is better)")
axes[0, 0].legend(fontsize=8)
fig.tight_layout()
plt.show()
