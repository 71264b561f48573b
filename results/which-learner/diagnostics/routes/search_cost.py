"""CPU time of one route's search of (k, lambda) before and after the residual's elimination from
the Gauss-Newton step and the reverse-mode Jacobian, side by side in one process:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/which-learner/diagnostics/routes/search_cost.py PRESET N SEED ROUTE OUT.json

For the point's adaptive learner (``_point.setup``: the runner's line-up, its flat start and rng),
``SharingSearch(route=ROUTE).search`` runs twice: with ``solver_options={"ridge": "stack"}`` inside
``jacobian_mode("forward")`` (the code before: the stacked (m + p + k) x (k + p) system QR-factored
whole, p tangent right-hand sides), then with the defaults (``ridge="eliminate"``, ``"auto"``).
Both start from the same random state. Records each run's CPU time (``time.process_time``), its chosen pair, and the largest difference of
the candidates' mean held-out scores between the two.
"""
import copy
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from _point import setup  # noqa: E402

from factirl_opt.learners.selection import SharingSearch  # noqa: E402
from factirl_opt.objectives import jacobian_mode  # noqa: E402

P = setup(sys.argv[1:4] + [sys.argv[5]])
route = sys.argv[4]
rng = copy.deepcopy(P.learner.rng)  # each run starts from the same random state
out = {"preset": P.preset.name, "n_tasks": P.n, "seed": int(sys.argv[3]), "route": route, "runs": {}}
for name, ridge, mode in (("before", "stack", "forward"), ("after", "eliminate", "auto")):
    learner = P.learner.set_params(sharing_search=SharingSearch(route=route), rng=copy.deepcopy(rng),
                                   solver_options={**(P.learner.solver_options or {}), "ridge": ridge})
    with jacobian_mode(mode):
        t0 = time.process_time()
        found = learner.sharing_search.search(learner, P.tasks, P.flat.rewards_)
        cpu = time.process_time() - t0
    out["runs"][name] = {"cpu_s": cpu, "chosen": [found.n_primitives, found.residual_penalty],
                         "scores": {f"{r['n_primitives']},{r['residual_penalty']}": r["score"] for r in found.rows}}
    print(name, cpu, out["runs"][name]["chosen"], flush=True)
a, b = out["runs"]["before"]["scores"], out["runs"]["after"]["scores"]
common = sorted(set(a) & set(b))
out["speedup"] = out["runs"]["before"]["cpu_s"] / out["runs"]["after"]["cpu_s"]
out["max_abs_score_diff"] = max((abs(a[c] - b[c]) for c in common), default=None)
out["same_candidates"] = set(a) == set(b)
print(out["speedup"], out["max_abs_score_diff"], out["same_candidates"], flush=True)
with open(P.out_path, "w") as f:
    json.dump(out, f, indent=1, default=float)
