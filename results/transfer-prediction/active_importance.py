"""Active requests ranked by the importance-sampled posterior, against random starts, on `bench active`'s worlds.

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/transfer-prediction/active_importance.py WORLD SEED [N_DRAWS]

Prints JSON. WORLD is ``grid`` or ``objectworld-per-task-quick``. The model, the test tasks, the
first demonstrations and the demonstrations' random transitions are `bench active`'s
(``factirl_opt.lab.benchmarks.active``: ``world``, ``demonstration_rng``, its model with
``transfer_stol=1e-3`` and no dictionary ensemble), so the ``random`` row is the benchmark's own
strategy run (``strategy_run``), and equals ``random`` in ``active_noise_WORLD_seedSEED.json``.

The ``importance`` row picks each next start from ``fo.learners.importance_posterior`` (N_DRAWS =
2000 draws, one generator per (seed, step)). For task ``i``:

- ``pi_j`` is draw ``j``'s greedy policy, ``w_j`` its weight, ``regret_j`` the regret of the model's
  policy ``pi`` (greedy on the transferred reward) under draw ``j``;
- ``u(s) = sum_j w_j regret_j [pi_j(s) != pi(s)]`` is the posterior regret that the expert's action in
  state ``s`` could refute;
- a start ``x`` is scored by ``sum_{t < L} (e_x P_pi^t) u``, the expected refutable regret along the
  ``L`` steps of a demonstration from ``x`` if the expert acted as the model does (``P_pi`` the MDP's
  transitions under ``pi``); the start of largest score is requested (ties: the lowest state).

Rows: the mean deviation of the transferred rewards after 1..8 demonstrations. The acceptance line
compares ``importance`` at 5 with ``random`` at 8.

Table of the committed runs (``active_importance_WORLD_seedSEED.json``; the mean curves of the first
seeds, then each seed's figures at 5 and 8):
``python results/transfer-prediction/active_importance.py table WORLD 0 1 2 7``
"""

import json
import sys

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.benchmarks.active import DEFAULTS, demonstration_rng, strategy_run, world
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.planning import plan


def start_scores(post, mdp, L):
    """The score (S,) of every start state for one task's :class:`ParticlePosterior` on its MDP."""
    planner = fo.planning.get_planner(mdp)
    draws = plan(planner, post.rewards(post.coefficients)).policy  # (n, S)
    pi = plan(planner, post.acted_rewards[None]).policy[0]
    u = (post.weights * post.regrets) @ (draws != pi[None, :])  # (S,)
    S, A = mdp.n_states, mdp.n_actions
    T = mdp.transition_matrix
    P = T[np.arange(S) * A + pi]
    P = P.toarray() if hasattr(P, "toarray") else np.asarray(P)
    score, occ = np.zeros(S), np.eye(S)
    for _ in range(L):
        score += occ @ u
        occ = occ @ P
    return score


def importance_run(model, gt, mdps, feats, n, seed, max_demos, n_draws):
    demos = [np.asarray(d) for d in gt.test_demos[:n]]
    L = demos[0].shape[1]
    m_list = mdps[:n] if isinstance(mdps, list) else mdps
    f_list = None if feats is None else feats[:n]
    out = {"deviation": [], "starts": []}
    for step in range(1, max_demos + 1):
        model.transfer(m_list, demos, features=f_list)
        out["deviation"].append(float(np.mean(fo.deviation(m_list, gt.test_rewards[:n], model.transfer_rewards_))))
        if step == max_demos:
            break
        posts = fo.learners.importance_posterior(model, n_draws, rng=np.random.default_rng([seed, step, 0x1A]))
        starts = []
        for i, post in enumerate(posts):
            env = mdps[i] if isinstance(mdps, list) else mdps
            starts.append(int(np.argmax(start_scores(post, env, L))))
        out["starts"].append(starts)
        for i in range(n):
            env = mdps[i] if isinstance(mdps, list) else mdps
            new = fo.sample_demonstrations(env, gt.test_rewards[i][None], 1, L, rng=demonstration_rng(seed, i, step),
                                           start=starts[i])[0]
            demos[i] = np.concatenate([demos[i], np.asarray(new)], axis=0)
    return out


def main(name, seed, n_draws=2000):
    s = {**DEFAULTS, "worlds": [name], "seeds": [seed], "transfer_stol": 1e-3}
    preset, gt, train_mdps, train_feats, test_mdps, test_feats = world(name, s, seed)
    n = min(s["n_test"], len(gt.test_demos))
    options = factorial_options(preset, preset.solvers, "policy-matching", features=train_feats is not None)
    model = fo.FactIRL(rng=seed, features=train_feats, **{**options, "transfer_stol": 1e-3})
    model.fit(train_mdps, gt.train_demos)
    rows = {"random": strategy_run(model, gt, preset, test_mdps, test_feats, n, "random", s, seed)["deviation"],
            "importance": importance_run(model, gt, test_mdps, test_feats, n, seed, s["max_demos"], n_draws)}
    starts = rows["importance"]["starts"]
    rows["importance"] = rows["importance"]["deviation"]
    return {"world": name, "seed": seed, "n_test": n, "n_draws": n_draws, "rows": rows, "importance_starts": starts,
            "importance_at_5": rows["importance"][4], "random_at_8": rows["random"][7]}


def table(name, seeds, held_out):
    import pathlib

    here = pathlib.Path(__file__).resolve().parent
    runs = {s: json.loads((here / f"active_importance_{name}_seed{s}.json").read_text()) for s in (*seeds, held_out)}
    print(f"#### {name}: mean of seeds {', '.join(map(str, seeds))}")
    print("| starts | " + " | ".join(str(i) for i in range(1, 9)) + " |")
    print("|---|" + "---|" * 8)
    for row in ("importance", "random"):
        mean = np.mean([runs[s]["rows"][row] for s in seeds], axis=0)
        print(f"| {row} | " + " | ".join(f"{v:.2f}" for v in mean) + " |")
    print()
    print("| seed | random at 8 | importance at 5 |")
    print("|---|---|---|")
    for s, run in runs.items():
        verdict = "no worse" if run["importance_at_5"] <= run["random_at_8"] else "worse"
        label = f"{s} (held out)" if s == held_out else str(s)
        print(f"| {label} | {run['random_at_8']:.2f} | {run['importance_at_5']:.2f} ({verdict}) |")
    at5 = np.mean([runs[s]["importance_at_5"] for s in seeds])
    at8 = np.mean([runs[s]["random_at_8"] for s in seeds])
    print(f"| mean of {', '.join(map(str, seeds))} | {at8:.3f} | {at5:.3f} ({'no worse' if at5 <= at8 else 'worse'}) |")


if __name__ == "__main__":
    if sys.argv[1] == "table":
        table(sys.argv[2], [int(a) for a in sys.argv[3:-1]], int(sys.argv[-1]))
    else:
        print(json.dumps(main(sys.argv[1], int(sys.argv[2]), *(int(a) for a in sys.argv[3:])), indent=2))
