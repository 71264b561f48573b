"""The default search, then its chosen k and neighbours at the chosen lambda rescored by candidate fits of B
outer iterations (a confirmation stage, not in the library), on one which-learner point, and the test
deviation of each pair chosen (run from the repository's root):
python results/which-learner/diagnostics/evidence-budget/confirm.py PRESET N SEED OUT.json B"""
import json
import sys
import time

sys.path.insert(0, "results/which-learner")
from factirl_opt.learners import adaptive  # noqa: E402
from factirl_opt.learners.selection import SharingSearch  # noqa: E402
from _point import setup, test_deviation  # noqa: E402

P = setup(sys.argv[1:5])
budget = int(sys.argv[5])

t0 = time.process_time()
found = SharingSearch().search(P.learner, P.tasks, P.flat.rewards_)
t_search = time.process_time() - t0
k, lam = found.n_primitives, found.residual_penalty
out = {"screen": {"chosen": [k, lam], "cpu_s": t_search}}
if lam != 0.0:
    trio = [(m, lam) for m in (k - 1, k, k + 1) if m >= 1]
    t0 = time.process_time()
    scores = adaptive.score_candidates(P.learner, P.tasks, P.flat.rewards_, found.folds, trio,
                                       candidate_max_iter=budget, transfer_max_iter=20)
    rows = adaptive.score_rows(scores)
    best = adaptive.choose_row(rows, "fewest-within-se")
    out["confirm"] = {"chosen": [rows[best]["n_primitives"], rows[best]["residual_penalty"]],
                      "cpu_s": time.process_time() - t0,
                      "rows": [(r["n_primitives"], r["residual_penalty"], r["score"]) for r in rows]}
    out["test_deviation"] = {f"{m},{lam}": test_deviation(P, m, lam) for m, _ in trio}
print(json.dumps(out, default=float), flush=True)
json.dump(out, open(sys.argv[4], "w"), indent=1, default=float)
