"""Diagnostic: per candidate, per held-out task scores (raw NLL, tempered NLL, agreement) + test deviation:
``python results/which-learner/scores.py PRESET N_TASKS SEED OUT.json``."""
import json
import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import log_softmax
from factirl_opt.learners import adaptive
from factirl_opt.learners.em import log_policies
from factirl_opt.planning import get_planner
from factirl_opt.tasks.demonstrations import empirical_statistics
from _point import held_out_transfers, setup, test_deviation

P = setup()
out_path, mdp, demos, cands = P.out_path, P.mdp, P.demos, P.cands
t = 1

def tempered(z, w):
    f = lambda c: -np.sum(w * log_softmax(c * z, axis=1))
    r = minimize_scalar(lambda lc: f(np.exp(lc)), bounds=(-8, 4), method="bounded")
    return min(f(np.exp(r.x)), f(0.0)), float(np.exp(r.x))

res = {str(c): {"raw": {}, "temp": {}, "agree": {}} for c in cands}
for fi, (k, lam), m, held in held_out_transfers(P, t):
    for j, i in enumerate(held):
        tm = adaptive.task_mdp(mdp, i)
        mu, pi_hat = empirical_statistics(tm, [demos[i][t:]])
        w = mu[0][:, None] * pi_hat[0]
        z = log_policies(get_planner(tm, m.planner), np.asarray(m.transfer_rewards_[j])[None], m.beta, m.objective)[0]
        res[str((k, lam))]["raw"][int(i)] = float(-np.sum(w * z))
        res[str((k, lam))]["temp"][int(i)] = tempered(z, w)[0]
        greedy = (z >= z.max(axis=1, keepdims=True) - 1e-12)
        res[str((k, lam))]["agree"][int(i)] = float(-np.sum(w * greedy / greedy.sum(axis=1, keepdims=True)))
    print(fi, (k, lam), {s: np.mean([res[str((k, lam))][s][int(i)] for i in held]) for s in ("raw", "temp", "agree")}, flush=True)
for (k, lam) in cands:
    dev = test_deviation(P, k, lam)
    res[str((k, lam))]["test"] = dev
    print("test", (k, lam), dev, {s: np.mean(list(res[str((k, lam))][s].values())) for s in ("raw", "temp", "agree")}, flush=True)
    json.dump(res, open(out_path, "w"))
