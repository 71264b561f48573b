"""One "which learner when" point for the diagnostics (`scores.py`, `occupancy_scores.py`): the ground
truth, the flat fit of the PCA start, the adaptive learner of the runner's line-up, its folds and
candidates, from the command line ``PRESET N_TASKS SEED OUT.json``."""
import sys
import types
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.experiments import PRESETS, make_ground_truth
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.lineup import RunContext
from factirl_opt.lab.experiments.runner import RunSpec
from factirl_opt.learners import adaptive
from factirl_opt.learners.fitting import learner_tasks


def setup(argv=None):
    warnings.simplefilter("ignore")
    argv = sys.argv[1:] if argv is None else argv
    preset, n, seed, out_path = PRESETS[argv[0]], int(argv[1]), int(argv[2]), argv[3]
    gt = make_ground_truth(preset, n, preset.default_demos, seed)
    if preset.world == "babyai":
        Ftr, Fte, demos, test_demos = gt.features("train"), gt.features("test"), gt.demos("train"), gt.demos("test")
    elif gt.task_maps:  # a map per task
        Ftr, Fte = list(gt.task_maps["train"].features), list(gt.task_maps["test"].features)
        demos, test_demos = gt.train_demos, gt.test_demos
    else:  # one map: Objectworld's features, or the grid's tabular rewards
        Ftr, Fte, demos, test_demos = (None if preset.world == "grid" else gt.features), None, gt.train_demos, gt.test_demos
    mdp = gt.mdps("train")
    ctx = RunContext(gt, RunSpec(n, preset.default_demos, seed))
    kw = factorial_options(preset, preset.solvers, adaptive=True, features=Ftr is not None)
    flat = fo.GradIRL(beta=preset.beta, features=Ftr, max_iter=preset.flat_max_iter, gtol=preset.flat_gtol,
                      stol=preset.flat_stol, solver=kw.get("flat_solver", "armijo"), planner=preset.planner).fit(mdp, demos)
    learner = fo.FactIRL(rng=ctx.rngs["pca"], features=Ftr, **kw)
    folds = adaptive.task_folds(n, 3, learner.rng)  # the folds of the search (SharingSearch(cv=3))
    tasks = learner_tasks(learner, mdp, demos)  # the task set the learner's fit builds
    k_max = adaptive.max_primitives(tasks, folds)
    return types.SimpleNamespace(preset=preset, n=n, out_path=out_path, gt=gt, Ftr=Ftr, Fte=Fte, mdp=mdp, demos=demos, tasks=tasks,
                                 test_demos=test_demos, flat=flat, learner=learner, folds=folds,
                                 cands=adaptive.sharing_candidates(learner, k_max))


def held_out_transfers(P, t=1):
    """For each fold and candidate: ``(fold, (k, lambda), model, held)``, the model fitted on the other
    folds' tasks and transferred to the held-out tasks from their first ``t`` demonstrations."""
    from factirl_opt.tasks.task_set import per_task_features

    for fi, held in enumerate(P.folds):
        train = np.setdiff1d(np.arange(P.n), held)
        sub_mdp, sub_F = adaptive.task_subset(P.mdp, P.Ftr, train)
        for k, lam in P.cands:
            m = adaptive.fixed_learner(P.learner, k, lam)
            m.features = sub_F
            m.fit(sub_mdp, adaptive.take_tasks(P.demos, train), flat_rewards=adaptive.take_tasks(P.flat.rewards_, train))
            hm, hF = adaptive.task_subset(P.mdp, P.Ftr, held)
            m.transfer(hm, [P.demos[i][:t] for i in held], features=hF if per_task_features(P.Ftr) else None)
            yield fi, (k, lam), m, held


def test_deviation(P, k, lam):
    """Mean test deviation of the candidate ``(k, lambda)`` fitted on all the point's training tasks
    (from the flat start) and transferred to its test tasks from their one demonstration."""
    m = adaptive.fixed_learner(P.learner, k, lam)
    m.fit(P.mdp, P.demos, flat_rewards=P.flat.rewards_)
    m.transfer(P.gt.mdps("test"), P.test_demos, features=P.Fte)
    return float(np.mean(fo.deviation(P.gt.mdps("test"), P.gt.rewards("test"), m.transfer_rewards_,
                                      planner=P.preset.planner)))
