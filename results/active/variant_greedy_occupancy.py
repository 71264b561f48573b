"""Variant measured, not adopted: request_starts with the occupancy of the greedy policy of the posterior mean
(the path the benchmark's greedy expert takes) instead of the model's Boltzmann policy, bench active's `requested`
strategy otherwise unchanged (``request_starts(..., policy="greedy")``).

Usage: OMP_NUM_THREADS=1 python results/active/variant_greedy_occupancy.py WORLD SEED
"""
import sys

from factirl_opt.lab.benchmarks import active as A
import factirl_opt.learners.factirl as F
from factirl_opt.lab.experiments.learner_solvers import factorial_options
world = sys.argv[1]; seed = int(sys.argv[2])
s = dict(A.DEFAULTS); s.update(worlds=[world], seeds=[seed], strategies=["requested"], n_test=30)
preset, gt, trm, trf, tem, tef = A.world(world, s, seed)
n = min(s["n_test"], len(gt.test_demos))
model = F.FactIRL(rng=seed, features=trf, **factorial_options(preset, preset.solvers, "policy-matching", features=trf is not None))
model.fit(trm, gt.train_demos)
out = A.strategy_run(model, gt, preset, tem, tef, n, "requested", s, seed, policy="greedy")
print("greedy-occ", world, seed, [round(x,2) for x in out["deviation"]])
