"""Constrained dictionaries (the paper's discussion): do nonnegative and/or sparse primitives recover the true ones better, and at what cost in deviation?

On the paper's grid world (default: the ``quick`` preset's size, 8x8, 40 training tasks x 10
demonstrations of 10 steps, k = 5, 15 test tasks with one demonstration, its budgets), for
each seed and each kind of true dictionary:

- ``gaussian``: the paper's, ``D ~ N(0, 1)`` (dense, mixed signs; :func:`factirl_opt.synthetic_tasks`);
- ``nonneg-sparse``: ``D = |N(0, 1)|`` kept with probability ``--density`` (nonnegative and
  sparse primitives, each with at least one nonzero entry);

the flat learner is fitted once and every FactIRL variant starts from the PCA of its rewards
(``flat_rewards``; ``pca_shrink=False`` as the presets): ``dictionary_constraint`` None (the
paper's), ``"nonneg"``, ``"sparse"`` and ``"nonneg-sparse"`` (L1 weight ``--alpha`` per task),
each then transferred to the test tasks from one demonstration.

Prints per (truth, variant) and seed: the matching score of the learnt primitives against the
true ones (:func:`factirl_opt.evaluation.dictionary_match`: mean absolute cosine of the
Hungarian matching; 1 = every true primitive recovered up to sign and scale), the fraction of
zero entries of the learnt dictionary, the mean train and test deviations (eq. 13) and the fit's
wall time; and the means over seeds (``summary``).

``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
"""

import time

import numpy as np

from ...parallel import limit_blas_threads
from ...datasets.synthetic import synthetic_tasks
from ...evaluation import deviation, dictionary_match
from ...learners.start import Start
from ...learners.dictionary import DICTIONARY_CONSTRAINTS, DictionaryConstraint
from ...learners.factirl import FactIRL
from ...learners.gradirl import GradIRL
from ...mdp.tabular import GridWorld
from ..arguments import integer, real
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "TRUTHS", "VARIANTS"]

#: the kinds of true dictionary
TRUTHS = ("gaussian", "nonneg-sparse")
#: the learnt dictionary's constraints compared ("none": the paper's free dictionary)
VARIANTS = ("none",) + DICTIONARY_CONSTRAINTS

DEFAULTS = {"size": 8, "n_tasks": 40, "n_demos": 10, "length": 10, "n_primitives": 5, "beta": 5.0,
            "flat_max_iter": 50, "max_iter": 30, "inner_steps": 5, "transfer_max_iter": 50, "n_test": 15,
            "alpha": 0.002, "density": 0.2, "seeds": [0, 1, 2], "truths": list(TRUTHS), "variants": list(VARIANTS),
            "blas_threads": 1}
QUICK = {"size": 4, "n_tasks": 8, "n_demos": 4, "length": 6, "n_primitives": 2, "flat_max_iter": 8, "max_iter": 4,
         "transfer_max_iter": 5, "n_test": 3, "seeds": [0]}


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--size", type=integer(2), help="grid side")
    opt("--n-tasks", type=integer(1), help="training tasks")
    opt("--n-demos", type=integer(1), help="demonstrations per training task")
    opt("--length", type=integer(1), help="steps per demonstration")
    opt("-k", "--n-primitives", type=integer(1), help="primitives, true and learnt")
    opt("--beta", type=real(0, low_open=True), help="Boltzmann inverse temperature")
    opt("--flat-max-iter", type=integer(0), help="GradIRL iterations (the PCA start)")
    opt("--max-iter", type=integer(0), help="FactIRL outer iterations")
    opt("--inner-steps", type=integer(1), help="FactIRL steps per sub-problem")
    opt("--transfer-max-iter", type=integer(0), help="transfer steps")
    opt("--n-test", type=integer(1), help="test tasks (one demonstration each)")
    opt("--alpha", type=real(0, low_open=True), help="L1 weight per task of the sparse variants")
    opt("--density", type=real(0, 1, low_open=True), help="probability that an entry of a nonneg-sparse true primitive is nonzero")
    opt("--seeds", type=integer(0), nargs="+", metavar="SEED", help="seeds (one problem each)")
    opt("--truths", choices=TRUTHS, nargs="+", metavar="KIND", help=f"true dictionaries, of {', '.join(TRUTHS)}")
    opt("--variants", choices=VARIANTS, nargs="+", metavar="NAME", help=f"learnt dictionaries, of {', '.join(VARIANTS)}")
    opt("--blas-threads", type=integer(0), help="OpenBLAS threads (0: leave as is)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny configuration for tests; options given explicitly keep their value")


def true_dictionary(kind, n_params, k, density, rng):
    """A true dictionary (p, k) of ``kind`` (see the module docstring)."""
    if kind == "gaussian":
        return rng.standard_normal((n_params, k))
    D = np.abs(rng.standard_normal((n_params, k))) * (rng.random((n_params, k)) < density)
    empty = ~np.any(D > 0, axis=0)
    D[rng.integers(0, n_params, size=int(empty.sum())), np.nonzero(empty)[0]] = 1.0
    return D


def _problem(s, mdp, kind, seed):
    rng = np.random.default_rng([seed, TRUTHS.index(kind)])
    D = true_dictionary(kind, mdp.n_params, s["n_primitives"], s["density"], rng)
    train = synthetic_tasks(mdp, s["n_tasks"], s["n_demos"], s["length"], dictionary=D, rng=rng)
    test = synthetic_tasks(mdp, s["n_test"], 1, s["length"], dictionary=D, rng=rng)
    return D, train, test


def _variant(s, mdp, train, test, flat, D_true, variant, seed):
    fact = FactIRL(s["n_primitives"], s["beta"], start=Start(init="pca", pca_shrink=False), max_iter=s["max_iter"],
                   inner_steps=s["inner_steps"], gtol=0.0, transfer_max_iter=s["transfer_max_iter"], rng=seed,
                   dictionary_constraint=DictionaryConstraint(None if variant == "none" else variant, alpha=s["alpha"]))
    t0 = time.perf_counter()
    fact.fit(mdp, train.demos, flat_rewards=flat)
    elapsed = time.perf_counter() - t0
    fact.transfer(mdp, test.demos)
    match, _, _ = dictionary_match(fact.dictionary_, D_true)
    return {"match": match, "zero_fraction": float(np.mean(fact.dictionary_ == 0)),
            "train_deviation": float(np.mean(deviation(mdp, train.rewards, fact.rewards_))),
            "test_deviation": float(np.mean(deviation(mdp, test.rewards, fact.transfer_rewards_))),
            "fit_time_s": elapsed, "n_evaluations": int(fact.n_evaluations_), "status": fact.status_}


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    t0 = time.perf_counter()
    with limit_blas_threads(s["blas_threads"]):
        runs = _runs(s)
    wall = time.perf_counter() - t0
    return {"settings": {k: v for k, v in s.items() if k != "quick"}, "wall_time_s": wall, "runs": runs,
            "summary": _summary(s, runs)}


def _runs(s):
    """Every (truth, seed): the flat fit, its PCA start's match, and every variant."""
    mdp = GridWorld(size=s["size"])
    runs = []
    for kind in s["truths"]:
        for seed in s["seeds"]:
            D_true, train, test = _problem(s, mdp, kind, seed)
            # gtol=0: flat fits stop by their loss tolerance, as in the committed runs
            flat = GradIRL(s["beta"], max_iter=s["flat_max_iter"], gtol=0.0, stol=0.0).fit(mdp, train.demos)
            pca_match = dictionary_match(np.linalg.svd(flat.rewards_.reshape(len(train.demos), -1),
                                                       full_matrices=False)[2][:s["n_primitives"]].T, D_true)[0]
            row = {"truth": kind, "seed": seed, "flat_train_deviation": float(np.mean(deviation(mdp, train.rewards, flat.rewards_))),
                   "pca_start_match": pca_match, "variants": {}}
            for variant in s["variants"]:
                row["variants"][variant] = _variant(s, mdp, train, test, flat.rewards_, D_true, variant, seed)
            runs.append(row)
    return runs


def _summary(s, runs):
    """Means over seeds per truth and variant."""
    summary = {}
    for kind in s["truths"]:
        rows = [r for r in runs if r["truth"] == kind]
        summary[kind] = {v: {m: float(np.mean([r["variants"][v][m] for r in rows]))
                             for m in ("match", "zero_fraction", "train_deviation", "test_deviation", "fit_time_s")}
                         for v in s["variants"]}
        summary[kind]["pca start"] = {"match": float(np.mean([r["pca_start_match"] for r in rows]))}
    return summary
