"""Test deviation of fixed (k, lambda) fits, from the point's flat start, transferred to its test tasks from one
demonstration, at one which-learner point (run from the repository's root):
python results/which-learner/diagnostics/evidence-budget/pairs.py PRESET N SEED OUT.json k,lam [k,lam ...]"""
import json, sys, time
sys.path.insert(0, "results/which-learner")
import numpy as np
import factirl_opt as fo
from factirl_opt.learners import adaptive
from _point import setup
P = setup(sys.argv[1:5])
out = {}
for pair in sys.argv[5:]:
    k, lam = pair.split(","); k, lam = int(k), float(lam)
    m = adaptive.fixed_learner(P.learner, k, lam)
    t0 = time.process_time(); m.fit(P.mdp, P.demos, flat_rewards=P.flat.rewards_); t = time.process_time() - t0
    m.transfer(P.gt.mdps("test"), P.test_demos, features=P.Fte)
    dev = float(np.mean(fo.deviation(P.gt.mdps("test"), P.gt.rewards("test"), m.transfer_rewards_, planner=P.preset.planner)))
    out[pair] = {"cpu_s": t, "test_deviation": dev}; print(pair, out[pair], flush=True)
    json.dump(out, open(sys.argv[4], "w"), indent=1)
