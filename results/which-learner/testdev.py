"""Test deviation of fixed (k, lambda) candidates fitted on all training tasks of a which-learner point and
transferred to its test tasks from one demonstration: python testdev.py PRESET N SEED OUT.json "k,lam" ..."""
import json, os, sys
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np
import factirl_opt as fo
from factirl_opt.learners import adaptive
from _point import setup
P = setup(sys.argv[1:5])
out = {}
for spec in sys.argv[5:]:
    k, lam = spec.split(","); k, lam = int(k), float(lam)
    m = adaptive.fixed_learner(P.learner, k, lam)
    m.fit(P.mdp, P.demos, flat_rewards=P.flat.rewards_)
    m.transfer(P.gt.mdps("test"), P.test_demos, features=P.Fte)
    dev = float(np.mean(fo.deviation(P.gt.mdps("test"), P.gt.rewards("test"), m.transfer_rewards_, planner=P.preset.planner)))
    out[spec] = dev
    print(spec, dev, flush=True)
    json.dump(out, open(P.out_path, "w"))
