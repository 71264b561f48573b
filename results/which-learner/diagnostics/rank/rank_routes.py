"""Each route's rank agreement with the candidates' test deviations beside today's held-out likelihood's
on the same candidates, on one which-learner point:

python rank_routes.py PRESET N SEED OUT.json ROUTES.json [ROUTES.json ...] [--deviations EARLIER.json ...]

ROUTES.json: records of ``routes.py --same-folds`` (or of one route run alone) on the point, every route on the
same folds; a route found in several files is taken from the last. One of them must hold the ``"full"`` route:
the exact K-fold held-out likelihood of fitted candidates (today's score, ``SharingSearch(route="full")``).

For each route, over the candidates it scored on every fold (``n``):

- ``rho_route``: Spearman's rho between the route's mean held-out scores and the candidates' test deviations
  (``_point.test_deviation``: fitted on all training tasks from the flat start, the test tasks transferred from
  one demonstration);
- ``rho_exact``: the same for the ``"full"`` route's exact held-out likelihood over the same candidates; the
  candidates the full route did not score (the evidence route's k, bisections) are scored here exactly as the
  full route scores (``adaptive.score_candidates`` on the same folds, from the same rng state);
- ``rho_route_exact``: the route's scores against the exact ones.

The race (``route="race"``) is derived, not run: its candidates are fitted and scored as the full route's (no
warm start, no budget), so its table is the full route's restricted to the grid candidates within
``RACE_MARGIN`` of the best on the first fold (and the flat model), which are scored on every fold, the others on
the first fold only; then the choice rule (``adaptive.choose_row``) and the bisection of k (``adaptive.bisection_midpoints``),
the bisected candidates' exact scores taken from the full table or scored here. Its scores are the exact ones,
so its ``rho_route`` is ``rho_exact`` over its candidates. (The race's flat model takes another candidate's fit
instead of its own; its transfer does not use the dictionary, so its score is the full route's flat fit's.)

``--deviations``: earlier records whose test deviations are taken instead of refitting (a ``rank.py`` record's
``test_deviation``, a ``rank_approx.py`` record's ``candidates[...]["test_deviation"]``), and the chosen pairs'
test deviations of ROUTES.json; only valid for records made with the same flat start (``routes.py``'s factorial
test deviation equal). ``check``: one candidate of the full table scored again here (the folds and code
reproduce the table when ``max_abs_diff`` is 0).
"""
import copy
import json
import os
import sys

import numpy as np
from scipy.stats import spearmanr

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from factirl_opt.learners import adaptive  # noqa: E402
from factirl_opt.learners.estimator import clone  # noqa: E402
from _point import setup, test_deviation  # noqa: E402

args = sys.argv[1:]
dev_files = args[args.index("--deviations") + 1:] if "--deviations" in args else []
args = args[:args.index("--deviations")] if "--deviations" in args else args
P = setup(args[:3] + [args[3]])
routes = {}
for path in args[4:]:
    routes.update(json.load(open(path))["routes"])
if "full" not in routes:
    raise SystemExit("no 'full' route among " + ", ".join(args[4:]))


def key(k, lam):
    return f"{int(k)},{float(lam)}"


def complete_rows(table):
    most = max(len(r["fold_scores"]) for r in table)
    return [r for r in table if len(r["fold_scores"]) == most and most > 0]


# test deviations already measured with this flat start
devs = {}
for path in dev_files:
    d = json.load(open(path))
    if "candidates" in d:
        devs.update({c: v["test_deviation"] for c, v in d["candidates"].items() if "test_deviation" in v})
    devs.update(d.get("test_deviation", {}))
for v in routes.values():
    devs.setdefault(key(*v["chosen"]), v["test_deviation"])
    if "share_within_noise" in v:
        devs.setdefault(key(*v["share_within_noise"]["chosen"]), v["share_within_noise"]["test_deviation"])
reused = sorted(devs)

# the exact scores: the full route's table, and a scorer on its folds for the others
exact = {key(r["n_primitives"], r["residual_penalty"]): r for r in routes["full"]["table"]}
rng0 = copy.deepcopy(P.learner.rng)  # the state the search of a route run first (or with --same-folds) starts from
S = clone(P.learner)
S.set_params(rng=copy.deepcopy(rng0))
folds = adaptive.task_folds(P.n, adaptive.N_FOLDS, S.rng)  # as search_sharing draws them
k_max = adaptive.max_primitives(P.tasks, folds)
scored_here = []


def score_exactly(cands):
    """Rows of the full route's scores for ``cands`` (pairs), scored on ``folds`` as the full route does."""
    todo = [c for c in cands if key(*c) not in exact]
    if todo:
        scores = adaptive.score_candidates(S, P.tasks, P.flat.rewards_, folds, todo)
        for row in adaptive.score_rows(scores):
            exact[key(row["n_primitives"], row["residual_penalty"])] = row
            scored_here.append(key(row["n_primitives"], row["residual_penalty"]))
            print("exact", row["n_primitives"], row["residual_penalty"], row["score"], flush=True)
    return [exact[key(*c)] for c in cands]


# check: the cheapest grid candidate of the full table scored again
grid = adaptive.sharing_candidates(S, k_max)
probe = grid[0]
again = adaptive.score_rows(adaptive.score_candidates(S, P.tasks, P.flat.rewards_, folds, [probe]))[0]
check = {"candidate": list(probe), "max_abs_diff": float(np.max(np.abs(np.subtract(again["task_scores"],
                                                                                 exact[key(*probe)]["task_scores"]))))}
print("check", check, flush=True)

# the race, derived from the exact scores
sizes = [len(f) for f in folds]
first = {key(*c): score_exactly([c])[0] for c in grid}
lead = min(r["fold_scores"][0] for r in first.values())
contenders = [c for c in grid if first[key(*c)]["fold_scores"][0] <= lead + adaptive.RACE_MARGIN * abs(lead) or c[1] == 0.0]
race_scores = {}
for c in grid:
    per_task = np.split(np.asarray(first[key(*c)]["task_scores"]), np.cumsum(sizes)[:-1])
    race_scores[c] = list(per_task) if len(contenders) > 1 and c in contenders else per_task[:1]
rows = adaptive.score_rows(race_scores)
best = adaptive.choose_row(rows)
while P.learner.n_primitives == adaptive.AUTO and rows[best]["residual_penalty"] != 0.0:
    k, lam = rows[best]["n_primitives"], rows[best]["residual_penalty"]
    between = adaptive.bisection_midpoints(k, [c[0] for c in race_scores if c[1] == lam], k_max)
    if not between:
        break
    for row in score_exactly([(m, lam) for m in between]):
        race_scores[row["n_primitives"], row["residual_penalty"]] = np.split(np.asarray(row["task_scores"]),
                                                                             np.cumsum(sizes)[:-1])
    rows = adaptive.score_rows(race_scores)
    best = adaptive.choose_row(rows)
    if rows[best]["n_primitives"] == k:
        break
rows[best]["chosen"] = True
race = {"chosen": [rows[best]["n_primitives"], rows[best]["residual_penalty"]], "table": rows,
        "candidate_fits": int(sum(len(r["fold_scores"]) for r in rows)), "derived": True}
routes["race"] = race

# test deviations of every candidate a route scored on every fold, and of the chosen ones
need = {key(r["n_primitives"], r["residual_penalty"]) for v in routes.values() for r in complete_rows(v["table"])}
need |= {key(*v["chosen"]) for v in routes.values()}
for c in sorted(need - set(devs), key=lambda s: (int(s.split(",")[0]), -float(s.split(",")[1]))):
    k, lam = c.split(",")
    devs[c] = test_deviation(P, int(k), float(lam))
    print("test deviation", c, devs[c], flush=True)
race["test_deviation"] = devs[key(*race["chosen"])]


def rho(a, b):
    return float(spearmanr(a, b)[0]) if len(a) > 2 else None


out = {"preset": P.preset.name, "n_tasks": P.n, "seed": int(args[2]), "routes_files": args[4:],
       "deviations_files": dev_files, "folds": [f.tolist() for f in folds], "check": check,
       "exact_scored_here": scored_here, "test_deviation_reused": reused, "test_deviation": devs,
       "exact_score": {c: r["score"] for c, r in exact.items()}, "race_table": rows, "routes": {}}
for name, v in routes.items():
    rc = [r for r in complete_rows(v["table"]) if np.isfinite(r["score"])]
    cands = [(r["n_primitives"], r["residual_penalty"]) for r in rc]
    ex = [r["score"] for r in score_exactly(cands)] if cands else []
    d = [devs[key(*c)] for c in cands]
    out["routes"][name] = {"chosen": v["chosen"], "test_deviation": devs[key(*v["chosen"])], "n": len(rc),
                           "candidates": [list(c) for c in cands], "candidate_fits": v.get("candidate_fits"),
                           "rho_route": rho([r["score"] for r in rc], d), "rho_exact": rho(ex, d),
                           "rho_route_exact": rho([r["score"] for r in rc], ex)}
    print(name, {x: y for x, y in out["routes"][name].items() if x != "candidates"}, flush=True)
out["exact_score"] = {c: r["score"] for c, r in exact.items()}  # with those scored for the routes above
with open(P.out_path + ".tmp", "w") as f:
    json.dump(out, f, indent=1, default=float)
os.replace(P.out_path + ".tmp", P.out_path)
