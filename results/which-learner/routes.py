"""Search routes side by side on one which-learner point:
python routes.py PRESET N SEED OUT.json [--same-folds] [--score SCORE] [ROUTE ...]

For the point's adaptive learner (``_point.setup``: the runner's line-up, its flat start and rng), each
route of ``SharingSearch`` (default: every route of ``selection.ROUTES``) chooses ``(k, lambda)``; the
chosen pair is fitted on every training task from the flat start and transferred to the test tasks
from one demonstration (``_point.test_deviation``). Records per route the CPU time of the search
(``time.process_time``, this process), the chosen pair, its test deviation, and the CPU time of the
factorial fit with the preset's k from the same flat start (the benchmark's ``auto_cost_ratio``
compares the adaptive fit with that one: ratio = (search + final fit) / factorial fit, flat start
excluded on both sides).

Each search draws its folds from the learner's rng, so without ``--same-folds`` the second route's
folds are another permutation than the first's; with it, every route starts from the rng's state
before the first route (the same folds and candidate starts as a route run first or alone). ``--score``: the
held-out score of every route run (``SharingSearch(score=...)``; default: the search's default, recorded as
``score``).
"""
import copy
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from factirl_opt.learners import adaptive  # noqa: E402
from factirl_opt.learners.selection import DEFAULT_SCORE, ROUTES, SharingSearch  # noqa: E402
from _point import setup  # noqa: E402

import numpy as np  # noqa: E402
import factirl_opt as fo  # noqa: E402

P = setup(sys.argv[1:5])
rest = sys.argv[5:]
same_folds = "--same-folds" in rest
score = rest[rest.index("--score") + 1] if "--score" in rest else DEFAULT_SCORE
routes = [a for i, a in enumerate(rest) if a not in ("--same-folds", "--score") and (i == 0 or rest[i - 1] != "--score")] \
    or list(ROUTES)
rng0 = copy.deepcopy(P.learner.rng)
out = {"preset": P.preset.name, "n_tasks": P.n, "seed": int(sys.argv[3]), "same_folds": same_folds, "score": score,
       "routes": {}}


def fit_and_transfer(k, lam):
    m = adaptive.fixed_learner(P.learner, k, lam)
    t0 = time.process_time()
    m.fit(P.mdp, P.demos, flat_rewards=P.flat.rewards_)
    t_fit = time.process_time() - t0
    m.transfer(P.gt.mdps("test"), P.test_demos, features=P.Fte)
    dev = float(np.mean(fo.deviation(P.gt.mdps("test"), P.gt.rewards("test"), m.transfer_rewards_,
                                     planner=P.preset.planner)))
    return t_fit, dev


t_fact, dev_fact = fit_and_transfer(P.preset.n_primitives, np.inf)
out["factorial"] = {"n_primitives": P.preset.n_primitives, "cpu_s": t_fact, "test_deviation": dev_fact}
print("factorial", out["factorial"], flush=True)
for route in routes:
    if same_folds:
        P.learner.set_params(rng=copy.deepcopy(rng0))
    learner = P.learner.set_params(sharing_search=SharingSearch(route=route, score=score))
    t0 = time.process_time()
    found = learner.sharing_search.search(learner, P.tasks, P.flat.rewards_)
    t_search = time.process_time() - t0
    t_final, dev = fit_and_transfer(found.n_primitives, found.residual_penalty)
    out["routes"][route] = {"chosen": [found.n_primitives, found.residual_penalty], "search_cpu_s": t_search,
                            "final_cpu_s": t_final, "cost_ratio": (t_search + t_final) / t_fact,
                            "test_deviation": dev, "candidate_fits": int(sum(len(r["fold_scores"]) for r in found.rows)),
                            "table": found.rows}
    # the other rule on the same table: the pair that shares most within noise of the best
    row = found.rows[adaptive.choose_row(found.rows, "share-within-noise")]
    pair = [row["n_primitives"], row["residual_penalty"]]
    out["routes"][route]["share_within_noise"] = {
        "chosen": pair, "test_deviation": dev if pair == [found.n_primitives, found.residual_penalty]
        else fit_and_transfer(*pair)[1]}
    print(route, out["routes"][route], flush=True)
    with open(P.out_path, "w") as f:
        json.dump(out, f, indent=1, default=float)
