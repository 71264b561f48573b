"""The posterior and the requests of the README's ``"auto"`` model against one transfer, side by side in one process.

``python results/transfer/posterior_cost.py OUT.json [REPEATS] [BEFORE]``: the README's grid
(:func:`factirl_opt.lab.benchmarks.auto_cost.readme_grid`, seed 0: 30 training tasks x 10
demonstrations, 10 new tasks from one demonstration each), ``FactIRL(n_primitives="auto",
residual_penalty="auto")`` fitted on it (its choice: k and lambda in the record), then, REPEATS
times (default 2), in this order, CPU time (time.process_time) of: ``transfer`` (today's,
``transfer_stol=0``), ``transfer`` with the saturation rule (``transfer_stol=TRANSFER_STOL``),
``transfer_posterior_`` after the first (the low-rank posterior, the default), the dense posterior
(``laplace_posteriors(..., lowrank=False)``, as before), ``request_starts(n_requests=3)`` (the
posterior cached), and ``information_gains`` of every task over its parameters' determinants (as
before) for the ratio. The low-rank and dense posteriors, and the two gains, are compared (largest
absolute differences in the record). With BEFORE (a commit of this repository), also the requests
and the gains of ``factirl_opt/learners/active.py`` as it was at that commit, loaded beside
today's in the same process (``git show``), timed in the same repeat and compared: largest
absolute and relative differences of the gains, and whether every task ranks every start the same.
The transfers, ``transfer_posterior_`` and the requests (today's and before's) run under the
process's own BLAS threads, as a user's call does (the library's entry points limit them to
``FACTIRL_BLAS_THREADS``); the references (the dense posterior, the gains' direct calls) under
one thread. The committed record is of a run with one BLAS thread for the whole process
(``OPENBLAS_NUM_THREADS=1``); ``posterior_cost_threads.json`` of one under the machine's
default (two).
"""
import importlib.util
import json
import pathlib
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.benchmarks.auto_cost import readme_grid
from factirl_opt.learners.active import information_gains, start_occupancy, state_information
from factirl_opt.learners.posterior import coefficient_prior, laplace_posteriors, transfer_problem
from factirl_opt.learners.transfer import TRANSFER_STOL
from factirl_opt.parallel import limit_blas_threads


def cpu(fn):
    t0 = time.process_time()
    out = fn()
    return out, time.process_time() - t0


def cpu1(fn):
    """:func:`cpu` with BLAS limited to one thread: the references, which are not the library's entry points."""
    with limit_blas_threads(1):
        return cpu(fn)


def dense_gains(post, beta, length):
    """``log det(Lambda + H_s) - log det(Lambda)`` of every start over the posterior's parameters (before)."""
    pl, info, pi = state_information(post, "policy-matching", beta)
    occ = start_occupancy(pl, pi, np.arange(post.mdp.n_states), length)
    Lam = np.linalg.inv(post.covariance)
    H = np.einsum("cy,yde->cde", occ, info)
    return np.linalg.slogdet(Lam[None] + H)[1] - np.linalg.slogdet(Lam)[1]


def module_at(commit):
    """``factirl_opt.learners.active`` as it was at ``commit``, loaded beside today's (its relative imports resolve to today's package)."""
    root = pathlib.Path(__file__).resolve().parents[2]
    source = subprocess.run(["git", "-C", str(root), "show", f"{commit}:factirl_opt/learners/active.py"],
                            capture_output=True, text=True, check=True).stdout
    path = pathlib.Path(tempfile.mkdtemp()) / "active_before.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(f"factirl_opt.learners.active_at_{commit}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def same_ranking(gains, other):
    return all(np.array_equal(np.argsort(-a, kind="stable"), np.argsort(-b, kind="stable")) for a, b in zip(gains, other))


def main(out_path, repeats=2, commit=None):
    old = module_at(commit) if commit else None
    g = readme_grid(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        flat = fo.GradIRL(beta=5.0).fit(g.mdp, g.train_demos)
        model, fit_s = cpu(lambda: fo.FactIRL(n_primitives="auto", residual_penalty="auto", init="pca").fit(
            g.mdp, g.train_demos, flat_rewards=flat.rewards_))
    record = {"k": int(model.n_primitives_), "lambda": float(model.residual_penalty_), "fit_cpu": fit_s, "before": commit,
              "runs": []}
    for _ in range(repeats):
        run = {}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model.set_params(transfer_stol=TRANSFER_STOL)
            _, run["transfer_saturation"] = cpu(lambda: model.transfer(g.mdp, g.test_demos))
            run["saturation_status"] = model.transfer_status_
            run["saturation_deviation"] = float(fo.deviation(g.mdp, g.test_rewards, model.transfer_rewards_).mean())
            model.set_params(transfer_stol=0.0)
            _, run["transfer"] = cpu(lambda: model.transfer(g.mdp, g.test_demos))
        run["transfer_status"] = model.transfer_status_
        run["transfer_deviation"] = float(fo.deviation(g.mdp, g.test_rewards, model.transfer_rewards_).mean())
        run["warnings"] = sorted({type(w.message).__name__ for w in caught})
        posts, run["posterior"] = cpu(lambda: model.transfer_posterior_)
        problem = transfer_problem(model, g.mdp, g.test_demos)
        start = np.concatenate([model.transfer_coefficients_, model.transfer_residuals_], axis=1)
        dense, run["posterior_dense"] = cpu1(lambda: laplace_posteriors(problem, coefficient_prior(model.coefficients_),
                                                                      start, lowrank=False))
        run["posterior_mean_max_diff"] = float(max(np.abs(a.mean - b.mean).max() for a, b in zip(posts, dense)))
        run["posterior_covariance_max_diff"] = float(max(np.abs(a.covariance - b.covariance).max()
                                                         for a, b in zip(posts, dense)))
        run["covariance_max"] = float(max(np.abs(a.covariance).max() for a in dense))
        _, run["request_starts"] = cpu(lambda: model.request_starts(g.mdp, g.test_demos, 3))
        gains, run["gains"] = cpu1(lambda: [information_gains(p, "policy-matching", model.beta, np.arange(g.mdp.n_states), 10)
                                           for p in posts])
        dense, run["gains_dense"] = cpu1(lambda: [dense_gains(p, model.beta, 10) for p in posts])
        run["gains_max_diff"] = float(max(np.abs(a - b).max() for a, b in zip(gains, dense)))
        run["gains_max"] = float(max(np.abs(b).max() for b in dense))
        run["same_ranking"] = same_ranking(gains, dense)
        keys = ["posterior", "posterior_dense", "request_starts"]
        if old is not None:
            starts = model.request_starts(g.mdp, g.test_demos, 3)
            old_starts, run["request_starts_before"] = cpu(lambda: old.request_starts(model, g.mdp, g.test_demos, 3))
            run["same_requests_as_before"] = all(np.array_equal(a, b) for a, b in zip(starts, old_starts))
            was, run["gains_before"] = cpu1(lambda: [old.information_gains(p, "policy-matching", model.beta,
                                                                          np.arange(g.mdp.n_states), 10) for p in posts])
            run["gains_max_diff_before"] = float(max(np.abs(a - b).max() for a, b in zip(gains, was)))
            run["gains_max_rel_diff_before"] = float(max((np.abs(a - b) / np.abs(b)).max() for a, b in zip(gains, was)))
            run["same_ranking_as_before"] = same_ranking(gains, was)
            run["request_starts_over_before"] = run["request_starts"] / run["request_starts_before"]
            run["gains_over_before"] = run["gains"] / run["gains_before"]
            keys.append("request_starts_before")
        for key in keys:
            run[f"{key}_over_transfer"] = run[key] / run["transfer"]
            run[f"{key}_over_saturation_transfer"] = run[key] / run["transfer_saturation"]
        print(json.dumps(run), flush=True)
        record["runs"].append(run)
        model.transfer(g.mdp, g.test_demos[::-1])  # another task list: the next repeat builds its posterior again
    with open(out_path, "w") as f:
        json.dump(record, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 2, sys.argv[3] if len(sys.argv) > 3 else None)
