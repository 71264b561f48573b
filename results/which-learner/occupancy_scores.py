"""Diagnostic: per candidate and held-out task, tempered NLL and feature-expectation distance of the greedy
policy (from the held-out demos' start states, over their horizon) against the demos'; plus test deviation."""
import json
import numpy as np
import factirl_opt as fo
from factirl_opt.learners import adaptive
from factirl_opt.tasks.task_set import per_task_features
from _point import held_out_transfers, setup, test_deviation

P = setup()
out_path, Ftr, mdp, demos, cands = P.out_path, P.Ftr, P.mdp, P.demos, P.cands
t = 1

def feat(i):
    """Task i's features (None for tabular rewards: the state-action indicators)."""
    if Ftr is None:
        return None
    return np.asarray(Ftr[i] if per_task_features(Ftr) else Ftr)

def fe_distance(tm, F, R, dem):
    """|| Phi^T (occupancy of greedy pi from demo starts) - Phi^T (empirical discounted occupancy) ||_2 / horizon-normaliser."""
    S, A, g = tm.n_states, tm.n_actions, tm.gamma
    _, pol = fo.optimal_q(tm, np.asarray(R)[None])
    pol = np.asarray(pol[0])
    if pol.ndim == 1:
        pi = np.zeros((S, A)); pi[np.arange(S), pol] = 1.0
    else:
        pi = pol
    P = tm.csr()
    eps = [np.asarray(e) for e in dem]
    L = max(len(e) for e in eps)
    d = np.zeros(S)
    for e in eps: d[e[0, 0]] += 1.0 / len(eps)
    occ_pi = np.zeros((S, A)); occ_e = np.zeros((S, A))
    for e in eps:
        for k, (s, a) in enumerate(e): occ_e[s, a] += g ** k / len(eps)
    for k in range(L):
        x = d[:, None] * pi
        occ_pi += g ** k * x
        d = P.T @ x.reshape(-1)
    diff = (occ_pi - occ_e).reshape(-1)
    if F is None:
        return float(np.linalg.norm(diff)), float(np.abs(diff).sum())
    Fs = F if F.shape[0] == S * A else np.repeat(F, A, axis=0)
    return float(np.linalg.norm(Fs.T @ diff)), float(np.abs(diff).sum())

res = {str(c): {"temp": {}, "fe": {}, "tv": {}} for c in cands}
for fi, (k, lam), m, held in held_out_transfers(P, t):
    for j, i in enumerate(held):
        tm = adaptive.task_mdp(mdp, i)
        R = np.asarray(m.transfer_rewards_[j])
        res[str((k, lam))]["temp"][int(i)] = adaptive.held_out_nll(tm, demos[i][t:], R, m)
        fe, tv = fe_distance(tm, feat(i), R, demos[i][t:])
        res[str((k, lam))]["fe"][int(i)] = fe; res[str((k, lam))]["tv"][int(i)] = tv
    print(fi, (k, lam), {s: round(np.mean([res[str((k, lam))][s][int(i)] for i in held]), 4) for s in ("temp", "fe", "tv")}, flush=True)
json.dump(res, open(out_path, "w"))
for (k, lam) in cands:
    dev = test_deviation(P, k, lam)
    res[str((k, lam))]["test"] = dev
    print("test", (k, lam), dev, {s: round(np.mean(list(res[str((k, lam))][s].values())), 4) for s in ("temp", "fe", "tv")}, flush=True)
    json.dump(res, open(out_path, "w"))
