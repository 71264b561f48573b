"""Variants of the evidence's k on a few which-learner points:
``python results/which-learner/evidence_variants.py``

The matrix the PCA start decomposes (``learners.evidence.flat_start_points``, tasks as rows) scored
as the ``"evidence"`` route does (uncentred, rows as samples) and four ways it does not: centred;
transposed (the reward coordinates as samples, tasks as dimensions), uncentred and centred; the
columns standardised. Prints one line per point.
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from factirl_opt.learners.evidence import flat_start_points, pca_rank_evidence  # noqa: E402
from _point import setup  # noqa: E402

POINTS = [("sharing-grid", 5, 0), ("sharing-grid", 20, 0), ("sharing-grid", 20, 1), ("sharing-grid", 20, 2),
          ("sharing-grid", 100, 0), ("sharing-objectworld-quick", 5, 0), ("sharing-objectworld-quick", 20, 0),
          ("sharing-objectworld-quick", 20, 1), ("sharing-objectworld-per-task-quick", 5, 0),
          ("sharing-objectworld-per-task-quick", 20, 0)]
for preset, n, seed in POINTS:
    P = setup([preset, str(n), str(seed), os.devnull])
    Y = flat_start_points(P.tasks, P.flat.rewards_)
    sd = Y.std(axis=0)
    keep = sd > 1e-12 * sd.max()
    print(preset, n, seed, Y.shape, "rows", pca_rank_evidence(Y)[1], "rows-centred", pca_rank_evidence(Y, center=True)[1],
          "transposed", pca_rank_evidence(Y.T)[1], "transposed-centred", pca_rank_evidence(Y.T, center=True)[1],
          "standardised", pca_rank_evidence(Y[:, keep] / sd[keep])[1], flush=True)
