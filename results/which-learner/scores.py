"""Diagnostic: per candidate, per held-out task scores (raw NLL, tempered NLL, agreement) + test deviation."""
import sys, json, warnings
import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import log_softmax
import factirl_opt as fo
from factirl_opt.learners import adaptive
from factirl_opt.learners.em import log_policies
from factirl_opt.planning import get_planner
from factirl_opt.tasks.demonstrations import empirical_statistics
from factirl_opt.tasks.task_set import per_task_features
from factirl_opt.lab.experiments import PRESETS, make_ground_truth
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.lineup import RunContext
from factirl_opt.lab.experiments.runner import RunSpec
warnings.simplefilter("ignore")

preset = PRESETS[sys.argv[1]]; n = int(sys.argv[2]); seed = int(sys.argv[3]); out_path = sys.argv[4]
gt = make_ground_truth(preset, n, preset.default_demos, seed)
per_task = bool(gt.task_maps)
Ftr = list(gt.task_maps["train"].features) if per_task else (gt.features if preset.name.find("grid") < 0 else None)
print("features", None if Ftr is None else "yes", flush=True)
Fte = list(gt.task_maps["test"].features) if per_task else None
ctx = RunContext(gt, RunSpec(n, preset.default_demos, seed))
feat = Ftr is not None
kw = factorial_options(preset, preset.solvers, adaptive=True, features=feat)
mdp = gt.mdps("train"); demos = gt.train_demos
flat = fo.GradIRL(beta=preset.beta, features=Ftr, max_iter=preset.flat_max_iter, solver=kw.get("flat_solver", "armijo"),
                  planner=preset.planner).fit(mdp, demos)
learner = fo.FactIRL(init="pca", rng=ctx.rngs["pca"], features=Ftr, **kw)
from factirl_opt._validation import as_rng
folds = np.array_split(as_rng(learner.rng).permutation(n), 3)
p = adaptive._reward_dimension(learner, mdp)
k_max = min(p, min(n - len(f) for f in folds))
cands = adaptive._candidates("auto", "auto", k_max, False)
t = 1

def tempered(z, w):
    f = lambda c: -np.sum(w * log_softmax(c * z, axis=1))
    r = minimize_scalar(lambda lc: f(np.exp(lc)), bounds=(-8, 4), method="bounded")
    return min(f(np.exp(r.x)), f(0.0)), float(np.exp(r.x))

res = {str(c): {"raw": {}, "temp": {}, "agree": {}} for c in cands}
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
            mu, pi_hat = empirical_statistics(tm, [demos[i][t:]])
            w = mu[0][:, None] * pi_hat[0]
            z = log_policies(get_planner(tm, m.planner), np.asarray(m.transfer_rewards_[j])[None], m.beta, m.objective)[0]
            res[str((k, lam))]["raw"][int(i)] = float(-np.sum(w * z))
            res[str((k, lam))]["temp"][int(i)] = tempered(z, w)[0]
            greedy = (z >= z.max(axis=1, keepdims=True) - 1e-12)
            res[str((k, lam))]["agree"][int(i)] = float(-np.sum(w * greedy / greedy.sum(axis=1, keepdims=True)))
        print(fi, (k, lam), {s: np.mean([res[str((k, lam))][s][int(i)] for i in held]) for s in ("raw", "temp", "agree")}, flush=True)
for (k, lam) in cands:
    m = adaptive.fixed_learner(learner, k, lam)
    m.fit(mdp, demos, flat_rewards=flat.rewards_)
    m.transfer(gt.mdps("test"), gt.test_demos, features=Fte)
    dev = float(np.mean(fo.deviation(gt.mdps("test"), gt.rewards("test"), m.transfer_rewards_, planner=preset.planner)))
    res[str((k, lam))]["test"] = dev
    print("test", (k, lam), dev, {s: np.mean(list(res[str((k, lam))][s].values())) for s in ("raw", "temp", "agree")}, flush=True)
    json.dump(res, open(out_path, "w"))
