"""Diagnostic: on one benchmark point, every (k, lambda) candidate's validation score (policy-matching loss and
Boltzmann log-likelihood on held-out demos) against its test deviation after transfer from one demonstration."""
import sys, json, warnings
import numpy as np
import factirl_opt as fo
from factirl_opt.learners import adaptive
from factirl_opt.lab.experiments import PRESETS, make_ground_truth
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.lineup import RunContext
from factirl_opt.lab.experiments.runner import RunSpec
from factirl_opt.learners.solver_settings import SolverSettings
from factirl_opt.planning import optimal_q
warnings.simplefilter("ignore")

preset = PRESETS[sys.argv[1]]; n = int(sys.argv[2]); seed = int(sys.argv[3])
gt = make_ground_truth(preset, n, preset.default_demos, seed)
per_task = bool(gt.task_maps)
Ftr = list(gt.task_maps["train"].features) if per_task else gt.features
Fte = list(gt.task_maps["test"].features) if per_task else None
ctx = RunContext(gt, RunSpec(n, preset.default_demos, seed))
kw = factorial_options(preset, preset.solvers, adaptive=True, features=True)
flat = fo.GradIRL(beta=preset.beta, features=Ftr, max_iter=preset.flat_max_iter, solver=preset.flat_features_solver,
                  planner=preset.planner).fit(gt.mdps("train"), gt.train_demos)
learner = fo.FactIRL(rng=ctx.rngs["pca"], features=Ftr, **kw)
k, lam, table = adaptive.choose_sharing(learner, gt.mdps("train"), gt.train_demos, flat.rewards_, search="full", score=(sys.argv[4] if len(sys.argv) > 4 else "likelihood"))
out = []
for row in table:
    m = adaptive.fixed_learner(learner, row["n_primitives"], row["residual_penalty"])
    m.fit(gt.mdps("train"), gt.train_demos, flat_rewards=flat.rewards_)
    m.transfer(gt.mdps("test"), gt.test_demos, features=Fte)
    dev = float(np.mean(fo.deviation(gt.mdps("test"), gt.rewards("test"), m.transfer_rewards_, planner=preset.planner)))
    out.append(dict(k=row["n_primitives"], lam=row["residual_penalty"], score=row["score"], chosen=row["chosen"], test=dev))
    print(out[-1], flush=True)
fl = fo.GradIRL(beta=preset.beta, features=Fte, max_iter=preset.flat_max_iter, solver=preset.flat_features_solver,
                planner=preset.planner).fit(gt.mdps("test"), gt.test_demos)
print("flat test", float(np.mean(fo.deviation(gt.mdps("test"), gt.rewards("test"), fl.rewards_, planner=preset.planner))))
