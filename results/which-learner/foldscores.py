"""Held-out (tempered NLL) scores on the bench's folds for given (k, lambda): python foldscores.py PRESET N SEED OUT.json "k,lam" ..."""
import json, os, sys
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np
from factirl_opt.learners import adaptive
from _point import setup
P = setup(sys.argv[1:5])
out = {}
for spec in sys.argv[5:]:
    k, lam = spec.split(","); c = (int(k), float(lam))
    s = adaptive.score_candidates(P.learner, P.tasks, P.flat.rewards_, P.folds, [c], n_transfer_demos=1,
                                  score="likelihood")[c]
    out[spec] = {"score": float(np.mean(np.concatenate(s))), "fold_scores": [float(np.mean(f)) for f in s],
                 "task_scores": [float(v) for v in np.concatenate(s)]}
    print(spec, out[spec]["score"], out[spec]["fold_scores"], flush=True)
    json.dump(out, open(P.out_path, "w"))
