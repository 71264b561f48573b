"""Transfer variants on one "which learner when" point: ``python results/transfer/points.py PRESET N_TASKS SEED OUT.json``.

Fits, as the benchmark's runner does (the point's ground truth, the flat start, the preset's
solvers): the factorial learner (the preset's k, lambda = inf) and, on the grid at 20 and 100
tasks, the adaptive learner's chosen (k, lambda) of the committed default run
(`results/which-learner/default`), as a fixed fit from the same flat start (elsewhere the
adaptive learner keeps the flat model, whose transfer no variant changes). Then transfers every
test task from its one demonstration and from 3 (2 more drawn from seed (seed, 7)) with each
variant:

- ``none``: today's maximum-likelihood transfer;
- ``fitted``: the MAP under the training coefficients' prior, its scale fitted by
  :func:`fit_prior_scale` (``run_transfer(prior=...)``);
- ``fitted-1se``: the largest scale whose held-out score is within one standard error of the best;
- ``saturation=T``: the maximum-likelihood transfer stopped by the saturation rule,
  ``FactIRL(transfer_stol=T)``;
- ``fitted+saturation=0.001``: the fitted MAP, stopped by the saturation rule too;
- ``posterior``: the posterior's mean (``transfer_posterior_``, the Laplace MAP).

Records per (learner, variant, demonstrations): each test task's deviation, the statuses, the
tasks that reached max_iter, the transfer's CPU time (time.process_time).

The records in points/ were computed by this script at commit ef1aec5, where the MAP was
``FactIRL(transfer_prior="fitted")`` with ``transfer_prior_scale_`` set, and the saturation rule
``run_transfer(stol=T)`` bound into ``FactIRL.transfer``; this version runs the same arithmetic
through the plain functions and ``FactIRL(transfer_stol=T)``.
"""
import json
import re
import sys
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning, MaxIterWarning
from factirl_opt.lab.experiments import PRESETS, make_ground_truth
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.learners.fitting import resolve_step_solver, task_objective
from factirl_opt.learners.posterior import choose_prior_scale, coefficient_prior, fit_prior_scale
from factirl_opt.learners.solver_settings import estimator_solvers
from factirl_opt.learners.transfer import run_transfer, transfer_prior_weights, transfer_tasks

ADAPTIVE_CHOICE = {  # results/which-learner/default/README.md, the grid's shared choices
    ("sharing-grid", 20, 0): (4, 1.0), ("sharing-grid", 20, 1): (5, np.inf), ("sharing-grid", 20, 2): (6, 1.0),
    ("sharing-grid", 100, 0): (5, np.inf), ("sharing-grid", 100, 1): (5, np.inf), ("sharing-grid", 100, 2): (6, np.inf),
}
SATURATION = (1e-2, 1e-3, 1e-4)


def map_transfer(model, mdp, demos, features, scale, stol):
    """The MAP transfer of ``model`` (fitted) under its training coefficients' prior at ``scale``, as
    ``FactIRL.transfer`` sets the problem up (the model's solver, budgets and residual penalty)."""
    tasks, D = transfer_tasks(mdp, demos, features, model)
    obj = task_objective(tasks, model.beta, model.objective, model.planner)
    name, options = estimator_solvers(model)[:2]
    solver = resolve_step_solver(name, options, model.objective, "solver")
    prior = (*coefficient_prior(model.coefficients_), transfer_prior_weights(tasks, scale))
    return run_transfer(obj, D, solver, base_features=tasks.basis, max_iter=model.transfer_max_iter, tol=model.tol,
                        gtol=model.gtol, residual_penalty=model.residual_penalty_, prior=prior, stol=stol)


def more_demos(gt, preset, seed, n_more):
    """Each test task's one demonstration and ``n_more`` more of the preset's length."""
    rng = np.random.default_rng([seed, 7])
    mdps, R = gt.mdps("test"), gt.rewards("test")
    out = []
    for i, d in enumerate(gt.test_demos):
        m = mdps[i] if isinstance(mdps, (list, tuple)) else mdps
        extra = fo.sample_demonstrations(m, np.asarray(R[i])[None], n_demos=n_more, length=np.asarray(d).shape[1], rng=rng)[0]
        out.append(np.concatenate([np.asarray(d), np.asarray(extra)], axis=0))
    return out


def main(argv):
    preset, n, seed, out_path = PRESETS[argv[0]], int(argv[1]), int(argv[2]), argv[3]
    gt = make_ground_truth(preset, n, preset.default_demos, seed)
    if gt.task_maps:
        Ftr, Fte = list(gt.task_maps["train"].features), list(gt.task_maps["test"].features)
    else:
        Ftr, Fte = (None if preset.world == "grid" else gt.features), None
    mdp, demos = gt.mdps("train"), gt.train_demos
    test_mdp = gt.mdps("test")
    flat = fo.GradIRL(beta=preset.beta, features=Ftr, max_iter=preset.flat_max_iter, gtol=preset.flat_gtol,
                      stol=preset.flat_stol, solver=factorial_options(preset, preset.solvers, adaptive=True,
                                                                      features=Ftr is not None).get("flat_solver", "armijo"),
                      planner=preset.planner)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        flat.fit(mdp, demos)
    kw = factorial_options(preset, preset.solvers, features=Ftr is not None)
    models = {"factorial": dict(kw)}
    choice = ADAPTIVE_CHOICE.get((argv[0], n, seed))
    if choice is not None:
        akw = factorial_options(preset, preset.solvers, adaptive=True, features=Ftr is not None)
        akw.update(n_primitives=choice[0], residual_penalty=choice[1])
        akw.pop("sharing_search", None)
        models["adaptive"] = akw
    demo_sets = {1: gt.test_demos, 3: more_demos(gt, preset, seed, 2)}
    record = {"preset": argv[0], "n_tasks": n, "seed": seed, "learners": {}}
    for name, params in models.items():
        m = fo.FactIRL(rng=np.random.default_rng([seed, 3]), features=Ftr, **params)
        t0 = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m.fit(mdp, demos, flat_rewards=flat.rewards_)
        fit_cpu = time.process_time() - t0
        t0 = time.process_time()
        scale, scores = fit_prior_scale(m, mdp, demos, rule="min")
        scale_cpu = time.process_time() - t0
        se_scale = choose_prior_scale(scores, "1se")
        entry = {"k": int(m.n_primitives_), "lambda": float(m.residual_penalty_), "fit_cpu": fit_cpu,
                 "scale_cpu": scale_cpu, "scale": scale, "scale_1se": se_scale,
                 "held_out": {str(s): list(map(float, v)) for s, v in scores.items()}, "variants": {}}
        variants = [("none", None, 0.0), ("fitted", scale, 0.0), ("fitted-1se", se_scale, 0.0)]
        variants += [(f"saturation={t:g}", None, t) for t in SATURATION] + [("fitted+saturation=0.001", scale, 1e-3)]
        for t, dem in demo_sets.items():
            for vname, sc, stol in variants:
                t0 = time.process_time()
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    if sc:
                        res = map_transfer(m, test_mdp, dem, Fte, sc, stol)
                        rewards, status, reason, coef = res.rewards, res.status, res.reason, res.coefficients
                    else:
                        m.set_params(transfer_stol=stol)
                        m.transfer(test_mdp, dem, features=Fte)
                        rewards, status, reason = m.transfer_rewards_, m.transfer_status_, m.transfer_stop_reason_
                        coef = m.transfer_coefficients_
                cpu = time.process_time() - t0
                dev = np.asarray(fo.deviation(test_mdp, gt.rewards("test"), rewards, planner=preset.planner))
                hit = re.search(r"(\d+) at max_iter", reason)
                entry["variants"][f"{vname}@{t}"] = {
                    "deviation": dev.tolist(), "mean": float(dev.mean()), "cpu": cpu, "status": status, "reason": reason,
                    "max_iter_warnings": sum(isinstance(w.message, MaxIterWarning) for w in caught),
                    "max_iter_tasks": int(hit.group(1)) if hit else 0,
                    "other_warnings": [str(w.message)[:200] for w in caught if not isinstance(w.message, MaxIterWarning)],
                    "max_abs_coefficient": float(np.abs(coef).max())}
                print(name, vname, t, f"{dev.mean():.3f}", status, f"{cpu:.2f}s", flush=True)
            # the posterior's mean, from the ML transfer
            m.set_params(transfer_stol=0.0)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                m.transfer(test_mdp, dem, features=Fte)
                t0 = time.process_time()
                posts = m.transfer_posterior_
                cpu = time.process_time() - t0
            if posts is not None:
                Rp = [p.mean_rewards() for p in posts]
                Rp = Rp if isinstance(m.transfer_rewards_, list) else np.array(Rp)
                dev = np.asarray(fo.deviation(test_mdp, gt.rewards("test"), Rp, planner=preset.planner))
                entry["variants"][f"posterior@{t}"] = {"deviation": dev.tolist(), "mean": float(dev.mean()), "cpu": cpu}
                print(name, "posterior", t, f"{dev.mean():.3f}", f"{cpu:.2f}s", flush=True)
        record["learners"][name] = entry
    with open(out_path, "w") as f:
        json.dump(record, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1:])
