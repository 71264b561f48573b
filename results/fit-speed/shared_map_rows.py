"""The ``objectworld`` (one shared map) line-up's factorial training rows before and after the preset's switch.

On one draw of ``N`` training tasks (32 demonstrations of 16 steps on the preset's 32x32 map),
in one process, ``KIND`` (``tabular``: the ``flat`` and ``factorial`` rows on tabular rewards;
``features``: ``flat, features`` and ``factorial, features`` on the map's 217 features): the
flat row with ``flat_stol`` 0 (before) and 1e-5 (the preset's), then the PCA-start factorial
row from each with the alternation and the joint scheme, and the random-init row with each
scheme. Prints per fit: CPU s, evaluations, outer iterations, total loss, mean train deviation
(eq. 13), status and stop reason.

    PYTHONPATH=. OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/shared_map_rows.py 20 tabular
"""
import dataclasses, sys, time, warnings
import numpy as np
import factirl_opt as fo
from factirl_opt.lab.experiments.presets import get_preset
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.worlds import make_ground_truth
n, which = int(sys.argv[1]), sys.argv[2]  # N, KIND
preset = get_preset("objectworld")
gt = make_ground_truth(preset, n, 32, 0)
feats = None if which == "tabular" else gt.features
solver = preset.flat_solver if which == "tabular" else preset.flat_features_solver
def timed(m, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c = time.process_time(); m.fit(*a, **k); return time.process_time() - c
def dev(R):
    return float(np.mean(fo.deviation(gt.mdp, gt.train_rewards, np.asarray(R), planner=preset.planner)))
flats = {}
for stol in (0.0, 1e-5):
    flat = fo.GradIRL(beta=preset.beta, features=feats, max_iter=preset.flat_max_iter, gtol=0.0, stol=stol, solver=solver, planner=preset.planner)
    c = timed(flat, gt.mdp, gt.train_demos)
    flats[stol] = flat.rewards_
    print(which, "flat stol", stol, round(c, 1), flat.n_evaluations_, "%.3g" % float(np.sum(flat.loss_)), round(dev(flat.rewards_), 3), flat.stop_reason_[:60], flush=True)
for stol in (0.0, 1e-5):
    for scheme in ("alternating", "joint"):
        p = dataclasses.replace(preset, fact_scheme=scheme)
        m = fo.FactIRL(rng=np.random.default_rng(1), features=feats, **factorial_options(p, p.solvers))
        c = timed(m, gt.mdp, gt.train_demos, flat_rewards=flats[stol])
        print(which, "pca from stol", stol, scheme, round(c, 1), m.n_evaluations_, m.n_iter_, "%.4g" % float(np.sum(m.loss_)), round(dev(m.rewards_), 3), m.status_, m.stop_reason_[:80], flush=True)
for scheme in ("alternating", "joint"):
    p = dataclasses.replace(preset, fact_scheme=scheme)
    m = fo.FactIRL(rng=np.random.default_rng(2), features=feats, **factorial_options(p, p.solvers, init="random"))
    c = timed(m, gt.mdp, gt.train_demos)
    print(which, "random", scheme, round(c, 1), m.n_evaluations_, m.n_iter_, "%.4g" % float(np.sum(m.loss_)), round(dev(m.rewards_), 3), m.status_, m.stop_reason_[:80], flush=True)
