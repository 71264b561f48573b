"""What depends on the planner (the user guide's "Large MDPs"): the dense and sparse-LU planners
side by side at the same rewards, and along a fit.

At the same rewards (3 tasks of N(0, 1) state-action rewards, 3 demonstrations of 5 steps each, seeds
0-2), per world: the largest relative difference between the planners (max |a - b| / max |b|) of
the values (``optimal_q``'s Q and ``policy_evaluation``'s V of the greedy policy), of the losses
and their gradients (policy matching and MCE, beta 5) and of the scores (``deviation``); and
whether the greedy policies are equal. Worlds: the paper's 10x10 grid at gamma 0.9 and at 0.999,
and a 12x12 Objectworld (gamma 0.9).

Along a fit (the 10x10 grid, 10 tasks x 10 demonstrations of 10 steps, ``synthetic_tasks(...,
rng=7)``): GradIRL of 100 Armijo iterations (``stol=0``), then FactIRL, the paper's algorithm
(``PAPER_SETTINGS``, k = 5, ``rng=0``) from its rewards, once per planner; the relative
difference of the fitted rewards and of the final losses, and the mean train deviations.
Prints JSON:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/planners/agreement.py > results/planners/agreement.json
"""

import json

import numpy as np

import factirl_opt as fo

PLANNERS = ("dense", "sparse-lu")
WORLDS = {
    "grid, gamma 0.9": lambda: fo.GridWorld(size=10),
    "grid, gamma 0.999": lambda: fo.GridWorld(size=10, gamma=0.999),
    "objectworld, gamma 0.9": lambda: fo.objectworld.make_objectworld(size=12, rng=0).mdp(),
}
VALUES = ("Q", "V")
LOSSES = ("policy matching", "its gradient", "mce", "mce gradient", "deviation")


def relative(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def evaluations(mdp, R, R_other, demos, planner):
    Q, greedy = fo.optimal_q(mdp, R, planner=planner)
    mu, pi = fo.empirical_statistics(mdp, demos)
    pm, pm_grad = fo.policy_matching_loss(mdp, R, mu, pi, beta=5.0, planner=planner)
    mce, mce_grad = fo.mce_loss(mdp, R, mu, pi, beta=5.0, planner=planner)
    return greedy, {"Q": Q, "V": fo.policy_evaluation(mdp, R, greedy, planner=planner), "policy matching": pm,
                    "its gradient": pm_grad, "mce": mce, "mce gradient": mce_grad,
                    "deviation": fo.deviation(mdp, R, R_other, planner=planner)}


def main():
    out = {"same_rewards": {}, "fit": {}}
    for world, make in WORLDS.items():
        mdp = make()
        worst = {"values": 0.0, "losses, gradients and scores": 0.0, "greedy_equal": True, "by_quantity": {}}
        for seed in range(3):
            rng = np.random.default_rng(seed)
            R = rng.normal(size=(3, mdp.n_states, mdp.n_actions))
            demos = fo.sample_demonstrations(mdp, R, 3, 5, rng)
            fo.planning.clear_caches(mdp)
            greedy_dense, dense = evaluations(mdp, R, R[::-1] * 0.5, demos, "dense")
            greedy_sparse, sparse = evaluations(mdp, R, R[::-1] * 0.5, demos, "sparse-lu")
            for k in dense:
                worst["by_quantity"][k] = max(worst["by_quantity"].get(k, 0.0), relative(sparse[k], dense[k]))
            worst["greedy_equal"] &= bool(np.array_equal(greedy_dense, greedy_sparse))
            worst["values"] = max(worst["values"], *(relative(sparse[k], dense[k]) for k in VALUES))
            worst["losses, gradients and scores"] = max(worst["losses, gradients and scores"],
                                                        *(relative(sparse[k], dense[k]) for k in LOSSES))
        out["same_rewards"][world] = worst

    mdp = fo.GridWorld(size=10)
    tasks = fo.synthetic_tasks(mdp, 10, 10, 10, rng=7)
    fits = {}
    for planner in PLANNERS:
        fo.planning.clear_caches(mdp)
        execution = fo.Execution(planner=planner)
        flat = fo.GradIRL(max_iter=100, stol=0.0, execution=execution).fit(mdp, tasks.demos)
        fact = fo.FactIRL(n_primitives=5, rng=0, execution=execution, **fo.PAPER_SETTINGS).fit(
            mdp, tasks.demos, flat_rewards=flat.rewards_)
        fits[planner] = (flat, fact)
    (flat_d, fact_d), (flat_s, fact_s) = fits["dense"], fits["sparse-lu"]
    out["fit"] = {
        "gradirl_rewards": relative(flat_s.rewards_, flat_d.rewards_),
        "factirl_rewards": relative(fact_s.rewards_, fact_d.rewards_),
        "gradirl_loss": relative(flat_s.loss_, flat_d.loss_),
        "factirl_loss": relative(fact_s.loss_, fact_d.loss_),
        "gradirl_deviation": [float(fo.deviation(mdp, tasks.rewards, f.rewards_).mean()) for f in (flat_d, flat_s)],
        "factirl_deviation": [float(fo.deviation(mdp, tasks.rewards, f.rewards_).mean()) for f in (fact_d, fact_s)],
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
