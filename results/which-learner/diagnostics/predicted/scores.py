"""The held-out deviation score beside the held-out likelihood and the posterior's predicted regret, on one
which-learner point, every score computed from the same candidate fits on the same folds:

python scores.py PRESET N SEED OUT.json [RANK.json] [--dictionaries B] [--resume]

For each fold and candidate ``(k, lambda)`` the candidate is fitted on the other folds' tasks as the ``"full"``
route fits it (``fixed_learner`` with the learner's ``max_iter``, no warm start, from the flat start; ``check``
compares the likelihood's means with the full route's), and each held-out task is transferred from its first
demonstration; then, per held-out task:

- ``likelihood``: today's score, the tempered held-out likelihood of its other demonstrations (``held_out_nll``);
- ``deviation``: the new ``score="deviation"``: the transfer's deviation under the task's reference reward, the
  flat learner's reward of its other demonstrations (``reference_rewards``, fitted once), range-normalised
  (``held_out_deviation``);
- ``predicted``: the posterior's expected regret of acting on the transfer's posterior mean, from its one
  demonstration (``transfer_posterior_[i].sample_regrets(64, rng).mean()``); the conditional posterior, or with
  ``--dictionaries B`` the marginal one over ``B`` more dictionaries per candidate and fold, each refitted on all
  but one of ``B`` folds of the fold's training tasks (``PosteriorSettings(n_dictionaries=B, resampling="folds")``;
  their fits count in ``fit``); undefined (None) for the flat model;
- ``oracle``: the transfer's deviation under the task's true reward (what no search can see: the upper
  reference of any held-out score).

The CPU time (``time.process_time``) of each score, of the candidate fits, of the held-out transfers (which every
score needs) and of the reference fit (once per search) are recorded, and the deviation's cost relative to the
likelihood's: the scores alone, with the transfers, and for the whole search.
RANK.json (``diagnostics/rank/rank_*.json`` of the same point): its folds (checked equal to the ones drawn here)
and its full route's candidates; without it, the grid candidates of ``sharing_candidates``. ``check``: the
likelihood's means here against RANK.json's exact scores, made with the library of its day (the fits have moved
since: the likelihood here is ``score_candidates``'s of today, checked equal on two candidates). The candidates'
test deviations are fitted here (``_point.test_deviation``: on every training task from the flat start, the test
tasks transferred from one demonstration), not taken from RANK.json, for the same reason. ``--resume``: the scores
of OUT.json (a run of this script), without fitting them again; the test deviations and what follows from them
computed anew. One map (the grid, one-map Objectworld) only. Spearman's rho of each score's candidate means
against the test deviations, over the candidates every score defines, and for the likelihood and the deviation
also over all candidates (the flat model's predicted regret is undefined).
"""
import copy
import json
import os
import sys
import time

import numpy as np
from scipy.stats import spearmanr

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
import factirl_opt as fo  # noqa: E402
from factirl_opt.learners.estimator import clone  # noqa: E402
from factirl_opt.learners.selection import (N_FOLDS, fixed_learner, held_out_deviation, held_out_nll,  # noqa: E402
                                            max_primitives, reference_rewards, sharing_candidates, task_folds)
from _point import setup, test_deviation  # noqa: E402

N_DRAWS = 64
args = sys.argv[1:]
B = int(args[args.index("--dictionaries") + 1]) if "--dictionaries" in args else 0
args = args[:args.index("--dictionaries")] if "--dictionaries" in args else args
resume = "--resume" in args
args = [a for a in args if a != "--resume"]
P = setup(args[:4])
rank = json.load(open(args[4])) if len(args) > 4 else None
S = clone(P.learner)
S.set_params(rng=copy.deepcopy(P.learner.rng))  # the state a search run first (or with --same-folds) starts from
folds = task_folds(P.n, N_FOLDS, S.rng)
if rank is not None and [f.tolist() for f in folds] != rank["folds"]:
    raise SystemExit("the folds drawn here differ from RANK.json's")
k_max = max_primitives(P.tasks, folds)
cands = ([tuple(c) for c in rank["routes"]["full"]["candidates"]] if rank is not None
         else sharing_candidates(S, k_max))
planner = P.preset.planner
true_train = P.gt.rewards("train")


def key(k, lam):
    return f"{int(k)},{float(lam)}"


earlier = json.load(open(P.out_path)) if resume else None
t0 = time.process_time()
ref = None if resume else reference_rewards(S, P.tasks, 1)
cpu = {"reference": time.process_time() - t0, "fit": 0.0, "transfer": 0.0, "likelihood": 0.0, "deviation": 0.0, "predicted": 0.0,
       "oracle": 0.0}
names = ("likelihood", "deviation", "predicted", "oracle")
task_scores = {key(*c): {s: [] for s in names} for c in cands}
per_fit = []
for fi, held in ([] if resume else enumerate(folds)):
    train = np.setdiff1d(np.arange(P.n), held)
    for k, lam in cands:
        m = fixed_learner(S, k, lam, max_iter=S.max_iter,
                          **({"posterior": fo.PosteriorSettings(n_dictionaries=B, resampling="folds")} if B else {}))
        t0 = time.process_time()
        m.fit(P.mdp, [P.demos[i] for i in train], flat_rewards=[P.flat.rewards_[i] for i in train])
        ta = time.process_time()
        m.transfer(P.mdp, [P.demos[i][:1] for i in held])
        t1 = time.process_time()
        R = m.transfer_rewards_
        lik = [held_out_nll(P.mdp, P.demos[i][1:], R[j], m) for j, i in enumerate(held)]
        t2 = time.process_time()
        dev = [held_out_deviation(P.mdp, ref[i], R[j], planner) for j, i in enumerate(held)]
        t3 = time.process_time()
        posts = m.transfer_posterior_  # built from the transfer on first read
        pred = ([None] * len(held) if posts is None else
                [float(p.sample_regrets(N_DRAWS, np.random.default_rng([int(args[2]), int(i)]), planner).mean())
                 for p, i in zip(posts, held)])  # one generator per task: the same draws for every candidate
        t4 = time.process_time()
        orc = fo.deviation(P.mdp, np.asarray(true_train)[held], R, planner=planner)
        t5 = time.process_time()
        for s, v in zip(names, (lik, dev, pred, orc)):
            task_scores[key(k, lam)][s].extend(list(np.asarray(v, dtype=object)))
        cpu["fit"] += ta - t0
        cpu["transfer"] += t1 - ta
        cpu["likelihood"] += t2 - t1
        cpu["deviation"] += t3 - t2
        cpu["predicted"] += t4 - t3
        cpu["oracle"] += t5 - t4
        per_fit.append({"fold": fi, "candidate": [k, lam], "fit_s": ta - t0, "transfer_s": t1 - ta, "likelihood_s": t2 - t1, "deviation_s": t3 - t2,
                        "predicted_s": t4 - t3})
        print(fi, (k, lam), f"fit {ta - t0:.1f}s transfer {t1 - ta:.2f}s lik {np.mean(lik):.4f} ({t2 - t1:.2f}s) dev {np.mean(dev):.4f} "
              f"({t3 - t2:.2f}s) pred {None if posts is None else round(float(np.mean(pred)), 4)} ({t4 - t3:.2f}s) "
              f"oracle {np.mean(orc):.3f}", flush=True)

if resume:
    if earlier["candidates"] != [key(*c) for c in cands] or earlier["folds"] != [f.tolist() for f in folds]:
        raise SystemExit("OUT.json's candidates or folds are not this point's")
    task_scores, cpu, per_fit, B = earlier["task_scores"], earlier["cpu_s"], earlier["per_fit"], earlier.get("n_dictionaries", 0)
devs = {}
t0 = time.process_time()
for c in cands:
    devs[key(*c)] = test_deviation(P, *c)
    print("test deviation", key(*c), devs[key(*c)], flush=True)
cpu["test_deviations"] = time.process_time() - t0
means = {c: {s: (None if any(v is None for v in task_scores[c][s]) else float(np.mean(task_scores[c][s])))
             for s in names} for c in task_scores}
check = None
if rank is not None:
    check = {"max_abs_diff_likelihood_vs_rank_record": float(max(abs(means[key(*c)]["likelihood"] - rank["exact_score"][key(*c)])
                                                                for c in cands))}
    print("check", check, flush=True)


def rho(cs, s):
    a = [means[c][s] for c in cs]
    return float(spearmanr(a, [devs[c] for c in cs])[0]) if len(cs) > 2 else None


every = [key(*c) for c in cands]
shared = [c for c in every if means[c]["predicted"] is not None]
within = {lam: [c for c in every if float(c.split(",")[1]) == lam] for lam in (np.inf, 1.0)}
rhos = {"all": {s: rho(every, s) for s in ("likelihood", "deviation", "oracle")},
        "sharing": {s: rho(shared, s) for s in names},
        **{f"lambda={lam:g}": {s: rho(cs, s) for s in names} for lam, cs in within.items()}}
choice = {s: min((c for c in every if means[c][s] is not None), key=lambda c: means[c][s]) for s in names}
out = {"preset": P.preset.name, "n_tasks": P.n, "seed": int(args[2]), "rank_file": args[4] if rank is not None else None,
       "resumed": resume,
       "folds": [f.tolist() for f in folds], "n_draws": N_DRAWS,
       "n_dictionaries": B, "candidates": every, "check": check,
       "n": {"all": len(every), "sharing": len(shared)}, "rho": rhos, "cpu_s": cpu,
       # the scores alone; each with the held-out transfers it needs; the whole search (fits, transfers, score)
       "cost_ratio_deviation_to_likelihood": {
           "score": cpu["deviation"] / cpu["likelihood"],
           "transfers_and_score": (cpu["transfer"] + cpu["deviation"] + cpu["reference"]) / (cpu["transfer"] + cpu["likelihood"]),
           "search": (cpu["fit"] + cpu["transfer"] + cpu["deviation"] + cpu["reference"])
           / (cpu["fit"] + cpu["transfer"] + cpu["likelihood"])},
       "cost_ratio_predicted_to_likelihood": {
           "score": cpu["predicted"] / cpu["likelihood"],
           "transfers_and_score": (cpu["transfer"] + cpu["predicted"]) / (cpu["transfer"] + cpu["likelihood"])},
       "lowest_mean": {s: {"candidate": c, "test_deviation": devs[c]} for s, c in choice.items()},
       "test_deviation": {c: devs[c] for c in every}, "mean": means, "task_scores": task_scores, "per_fit": per_fit}
print("rho", json.dumps(rhos), "\ncpu", json.dumps(cpu), flush=True)
with open(P.out_path + ".tmp", "w") as f:
    json.dump(out, f, indent=1, default=float)
os.replace(P.out_path + ".tmp", P.out_path)
