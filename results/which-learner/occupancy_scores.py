"""Diagnostic: per candidate and held-out task, tempered NLL and feature-expectation distance of the greedy
policy (from the held-out demos' start states, over their horizon) against the demos'; plus test deviation."""
import sys, json, warnings
import numpy as np
import scipy.sparse as sp
import factirl_opt as fo
from factirl_opt.learners import adaptive
from factirl_opt.tasks.task_set import per_task_features
from factirl_opt.lab.experiments import PRESETS, make_ground_truth
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.lineup import RunContext
from factirl_opt.lab.experiments.runner import RunSpec
from factirl_opt._validation import as_rng
warnings.simplefilter("ignore")

preset = PRESETS[sys.argv[1]]; n = int(sys.argv[2]); seed = int(sys.argv[3]); out_path = sys.argv[4]
gt = make_ground_truth(preset, n, preset.default_demos, seed)
if hasattr(gt, "features") and callable(gt.features):      # BabyAI
    Ftr, Fte = gt.features("train"), gt.features("test")
elif gt.task_maps:
    Ftr, Fte = list(gt.task_maps["train"].features), list(gt.task_maps["test"].features)
else:
    Ftr, Fte = gt.features, None
mdp, demos = gt.mdps("train"), gt.demos("train") if hasattr(gt, "demos") and callable(gt.demos) else gt.train_demos
test_demos = gt.demos("test") if callable(getattr(gt, "demos", None)) else gt.test_demos
ctx = RunContext(gt, RunSpec(n, preset.default_demos, seed))
kw = factorial_options(preset, preset.solvers, adaptive=True, features=True)
flat = fo.GradIRL(beta=preset.beta, features=Ftr, max_iter=preset.flat_max_iter, solver=kw.get("flat_solver", "armijo"),
                  planner=preset.planner).fit(mdp, demos)
learner = fo.FactIRL(init="pca", rng=ctx.rngs["pca"], features=Ftr, **kw)
folds = np.array_split(as_rng(learner.rng).permutation(n), 3)
p = adaptive._reward_dimension(learner, mdp)
k_max = min(p, min(n - len(f) for f in folds))
cands = adaptive._candidates("auto", "auto", k_max, False)
t = 1

def feat(i):
    F = Ftr[i] if per_task_features(Ftr) else Ftr
    return np.asarray(F)

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
    Fs = F if F.shape[0] == S * A else np.repeat(F, A, axis=0) if F.shape[0] == S else F
    diff = (occ_pi - occ_e).reshape(-1)
    return float(np.linalg.norm(Fs.T @ diff)), float(np.abs(diff).sum())

res = {str(c): {"temp": {}, "fe": {}, "tv": {}} for c in cands}
for fi, held in enumerate(folds):
    train = np.setdiff1d(np.arange(n), held)
    sub_mdp, sub_F = adaptive._subset(mdp, Ftr, train)
    for (k, lam) in cands:
        m = adaptive.fixed_learner(learner, k, lam); m.features = sub_F
        m.fit(sub_mdp, adaptive._take(demos, train), flat_rewards=adaptive._take(flat.rewards_, train))
        hm, hF = adaptive._subset(mdp, Ftr, held)
        m.transfer(hm, [demos[i][:t] for i in held], features=hF if per_task_features(Ftr) else None)
        for j, i in enumerate(held):
            tm = adaptive._task_mdp(mdp, i)
            R = np.asarray(m.transfer_rewards_[j])
            res[str((k, lam))]["temp"][int(i)] = adaptive.held_out_nll(tm, demos[i][t:], R, m)
            fe, tv = fe_distance(tm, feat(i), R, demos[i][t:])
            res[str((k, lam))]["fe"][int(i)] = fe; res[str((k, lam))]["tv"][int(i)] = tv
        print(fi, (k, lam), {s: round(np.mean([res[str((k, lam))][s][int(i)] for i in held]), 4) for s in ("temp", "fe", "tv")}, flush=True)
json.dump(res, open(out_path, "w"))
for (k, lam) in cands:
    m = adaptive.fixed_learner(learner, k, lam)
    m.fit(mdp, demos, flat_rewards=flat.rewards_)
    m.transfer(gt.mdps("test"), test_demos, features=Fte)
    dev = float(np.mean(fo.deviation(gt.mdps("test"), gt.rewards("test"), m.transfer_rewards_, planner=preset.planner)))
    res[str((k, lam))]["test"] = dev
    print("test", (k, lam), dev, {s: round(np.mean(list(res[str((k, lam))][s].values())), 4) for s in ("temp", "fe", "tv")}, flush=True)
    json.dump(res, open(out_path, "w"))
