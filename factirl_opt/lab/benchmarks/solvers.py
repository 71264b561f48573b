"""H-step solvers side by side: Armijo descent vs Gauss-Newton QP steps (OSQP, Clarabel).

``python -m factirl_opt.lab.bench solvers [--quick]`` prints one JSON document with five parts,
all measured in the same run on the same data (a random ground-truth dictionary of
``--n-primitives`` primitive rewards on a ``--size`` x ``--size`` GridWorld):

- ``transfer``: the dictionary fixed to the ground truth, ``--transfer-tasks`` new tasks with
  ``--transfer-demos`` demonstration(s) of ``--demo-length`` steps each; ``FactIRL.transfer``
  from ``h = 0`` with ``--armijo-iter`` Armijo iterations and ``--gn-iter`` steps of every
  Gauss-Newton solver (``tol = 0`` and the maximum-likelihood transfer, ``transfer_stol = 0``:
  fixed budgets). Per solver: final loss (total and mean per
  task), batched Q* evaluations, wall time, mean deviation (eq. 13), QP fallbacks.
- ``fit``: a full ``FactIRL.fit`` on ``--fit-tasks`` training tasks (``--fit-demos`` demos each),
  PCA initialisation from one shared flat (GradIRL) fit, ``--fit-iter`` outer iterations of
  ``--inner-steps`` steps, for Armijo and each Gauss-Newton H-step (the D-step is Armijo).
  Every FactIRL of the benchmark is the paper's algorithm (``PAPER_SETTINGS``) with the H-step
  solver compared, whatever FactIRL's defaults.
- ``nonneg``: ground truth with nonnegative coefficients; transfer with the unconstrained and
  the nonneg variants: minimum learnt coefficient, mean deviation, loss.
- ``sparse``: ground truth with nonnegative sparse coefficients; transfer with the sparse
  variants for increasing ``--alphas``: exact zeros among the learnt coefficients.
- ``subproblem_timing``: per-task time of one block QP (all tasks' subproblems of an H-step,
  data from a real Gauss-Newton state) through cvxpy (compiled once, DPP re-solve with new
  parameter values) vs the same problem handed to the QP solver directly (OSQP workspace
  updated in place; Clarabel set up per call), and a fresh ``cp.Problem`` per task for scale.
  The data are those of ``--repeats`` successive LM steps of a transfer (median time kept).

``--quick`` shrinks everything (5x5 grid, a few tasks, short budgets) so a test can run it in
seconds. For stable timings on a shared machine run it with ``OPENBLAS_NUM_THREADS=1`` (the
solves are batches of small matrices; multi-threaded BLAS only adds contention); the
environment's BLAS settings are recorded in the output.
"""

import os
import time
import warnings

import numpy as np

import solvers

from ...tasks.demonstrations import empirical_statistics
from ...evaluation import deviation
from ...learners.start import Start
from ...learners.factirl import PAPER_SETTINGS, FactIRL
from ...learners.gradirl import GradIRL
from ...mdp.tabular import GridWorld
from ...objectives import PolicyMatchingObjective
from ...objectives.problems import weights_problem
from ...datasets.synthetic import random_dictionary, synthetic_tasks
from ..arguments import integer, real
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run"]

PARTS = ("transfer", "fit", "nonneg", "sparse", "subproblem_timing")
DEFAULTS = {
    "size": 10,
    "transfer_tasks": 50,
    "armijo_iter": 100,
    "gn_iter": 30,
    "sparse_gn_iter": 100,
    "fit_tasks": 30,
    "fit_demos": 10,
    "fit_iter": 10,
    "flat_iter": 100,
    "inner_steps": 5,
    "alphas": [0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0],
    "repeats": 20,
    "fresh_tasks": 10,
}
QUICK = {
    "size": 5,
    "transfer_tasks": 8,
    "armijo_iter": 20,
    "gn_iter": 6,
    "sparse_gn_iter": 6,
    "fit_tasks": 6,
    "fit_demos": 3,
    "fit_iter": 2,
    "flat_iter": 10,
    "inner_steps": 2,
    "alphas": [0.0, 0.1, 100.0],
    "repeats": 3,
    "fresh_tasks": 2,
}


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes and budgets (seconds; for tests); options given explicitly keep their value")
    parser.add_argument("--seed", type=integer(0), default=0, help="seed of the ground truth (default: 0)")
    opt("--size", type=integer(2), help="grid side")
    parser.add_argument("--n-primitives", type=integer(1), default=5, help="primitives, true and learnt (default: 5)")
    parser.add_argument("--beta", type=real(0, low_open=True), default=5.0, help="Boltzmann inverse temperature (default: 5.0)")
    opt("--transfer-tasks", type=integer(1), help="new tasks of the transfer, nonneg and sparse parts")
    parser.add_argument("--transfer-demos", type=integer(1), default=1, help="demonstrations per new task (default: 1)")
    parser.add_argument("--demo-length", type=integer(1), default=10, help="steps per demonstration (default: 10)")
    opt("--armijo-iter", type=integer(0), help="Armijo iterations of the transfer")
    opt("--gn-iter", type=integer(0), help="Gauss-Newton steps of the transfer")
    opt("--fit-tasks", type=integer(1), help="training tasks of the fit part")
    opt("--fit-demos", type=integer(1), help="demonstrations per training task")
    opt("--fit-iter", type=integer(0), help="FactIRL outer iterations")
    opt("--flat-iter", type=integer(0), help="GradIRL iterations of the PCA init")
    opt("--inner-steps", type=integer(1), help="FactIRL steps per sub-problem")
    opt("--sparse-gn-iter", type=integer(0), help="GN steps of the sparse sweep: zero counts are compared near convergence")
    opt("--alphas", type=real(0), nargs="+", help="L1 weights of the sparse sweep")
    parser.add_argument("--sparsity", type=real(0, 1, high_open=True), default=0.4, help="zero probability of the sparse ground truth (default: 0.4)")
    opt("--repeats", type=integer(1), help="timed re-solves per route (median kept)")
    opt("--fresh-tasks", type=integer(0), help="tasks timed with a fresh cp.Problem each")
    parser.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS,
                        help="parts to run (default: all)")


def _gn_names(constraint="none"):
    names = (solvers.qp_solver_name(qp_solver, constraint) for qp_solver in ("osqp", "clarabel"))
    return [n for n in names if n in solvers.available_solvers()]


def _paper_settings(name, options=None):
    """FactIRL's keyword arguments for the paper's algorithm (``PAPER_SETTINGS``: Armijo D-steps,
    the alternation, the maximum-likelihood transfer) with the H-step solver ``name``, so that
    every solver runs its fixed budget whatever FactIRL's defaults."""
    solver = PAPER_SETTINGS["solver"].with_overrides(h_solver=name, h_solver_options=options or None)
    return {**PAPER_SETTINGS, "solver": solver}


def _transfer(mdp, D, demos, true_R, name, iters, beta, **options):
    """FactIRL.transfer with the dictionary fixed; returns the measurements and the coefficients."""
    model = FactIRL(n_primitives=D.shape[1], beta=beta, **{**_paper_settings(name, options), "tol": 0.0})
    model.dictionary_ = D
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", solvers.QPFallbackWarning)
        t0 = time.perf_counter()
        H = model.transfer(mdp, demos, max_iter=iters)
        wall = time.perf_counter() - t0
    loss = float(np.sum(model.transfer_loss_))
    out = {
        "iterations": len(model.transfer_loss_history_) - 1,
        "status": model.transfer_status_,
        "final_loss": loss,
        "final_loss_per_task": loss / len(demos),
        "final_objective": float(model.transfer_loss_history_[-1]),
        "q_evaluations": int(model.transfer_n_evaluations_),
        "wall_time_s": wall,
        "mean_deviation": float(np.mean(deviation(mdp, true_R, model.transfer_rewards_))),
        "qp_fallback_warnings": sum(issubclass(w.category, solvers.QPFallbackWarning) for w in caught),
    }
    return out, H


def _tasks(mdp, s, rng, D, n_tasks, n_demos, kind="gaussian", sparsity=0.0):
    """New tasks drawn from the dictionary ``D`` with their demonstrations (:func:`synthetic_tasks`)."""
    return synthetic_tasks(mdp, n_tasks, n_demos, s["demo_length"], dictionary=D, kind=kind, sparsity=sparsity, rng=rng)


def _part_transfer(mdp, s, rng, D):
    tasks = _tasks(mdp, s, rng, D, s["transfer_tasks"], s["transfer_demos"])
    R, demos = tasks.rewards, tasks.demos
    for name in _gn_names():  # warm-up, untimed: cvxpy's and the QP solvers' one-off import costs
        _transfer(mdp, D, demos[:2], R[:2], name, 1, s["beta"])
    rows = {"armijo": _transfer(mdp, D, demos, R, "armijo", s["armijo_iter"], s["beta"])[0]}
    for name in _gn_names():
        rows[name] = _transfer(mdp, D, demos, R, name, s["gn_iter"], s["beta"])[0]
        rows[name + " (direct QP solver)"] = _transfer(mdp, D, demos, R, name, s["gn_iter"], s["beta"], interface="direct")[0]
    arm = rows["armijo"]
    checks = {}
    for name in _gn_names():
        r = rows[name]
        checks[name] = {
            "lower_loss_than_armijo": r["final_loss"] < arm["final_loss"],
            "evaluation_ratio_vs_armijo": r["q_evaluations"] / arm["q_evaluations"],
            "at_most_one_fifth_evaluations": 5 * r["q_evaluations"] <= arm["q_evaluations"],
            "deviation_ratio_vs_armijo": r["mean_deviation"] / max(arm["mean_deviation"], 1e-300),
            "deviation_within_10pct_or_better": r["mean_deviation"] <= 1.1 * arm["mean_deviation"],
        }
    return {
        "setting": {
            "grid": f"{s['size']}x{s['size']}",
            "tasks": s["transfer_tasks"],
            "demos_per_task": s["transfer_demos"],
            "demo_length": s["demo_length"],
            "dictionary": "ground truth (fixed)",
            "start": "h = 0",
            "armijo_iterations": s["armijo_iter"],
            "gn_steps": s["gn_iter"],
        },
        "solvers": rows,
        "acceptance": checks,
    }


def _part_fit(mdp, s, rng, D):
    tasks = _tasks(mdp, s, rng, D, s["fit_tasks"], s["fit_demos"])
    R, demos = tasks.rewards, tasks.demos
    t0 = time.perf_counter()
    # gtol=0: the flat fit stops by its loss tolerance, as in the committed runs
    flat = GradIRL(beta=s["beta"], max_iter=s["flat_iter"], gtol=0.0, stol=0.0).fit(mdp, demos)
    flat_time = time.perf_counter() - t0
    rows = {}
    for name in ["armijo"] + _gn_names():
        model = FactIRL(
            n_primitives=s["n_primitives"],
            beta=s["beta"],
            rng=0,
            **{**_paper_settings(name), "start": Start(init="pca"), "max_iter": s["fit_iter"],
               "inner_steps": s["inner_steps"], "tol": 0.0},
        )
        t0 = time.perf_counter()
        model.fit(mdp, demos, flat_rewards=flat.rewards_)
        wall = time.perf_counter() - t0
        rows[name] = {
            "outer_iterations": model.n_iter_,
            "final_loss": float(np.sum(model.loss_)),
            "final_loss_per_task": float(np.mean(model.loss_)),
            "q_evaluations": int(model.n_evaluations_),
            "wall_time_s": wall,
            "mean_deviation": float(np.mean(deviation(mdp, R, model.rewards_))),
        }
    return {
        "setting": {
            "tasks": s["fit_tasks"],
            "demos_per_task": s["fit_demos"],
            "outer_iterations": s["fit_iter"],
            "inner_steps": s["inner_steps"],
            "init": "pca of one shared GradIRL fit (its evaluations not counted)",
            "flat_fit": {"iterations": s["flat_iter"], "q_evaluations": int(flat.n_evaluations_), "wall_time_s": flat_time},
            "flat_mean_deviation": float(np.mean(deviation(mdp, R, flat.rewards_))),
        },
        "solvers": rows,
    }


def _part_nonneg(mdp, s, rng, D):
    tasks = _tasks(mdp, s, rng, D, s["transfer_tasks"], s["transfer_demos"], kind="nonneg")
    R, demos = tasks.rewards, tasks.demos
    rows = {}
    for name in _gn_names() + _gn_names("nonneg"):
        row, Hl = _transfer(mdp, D, demos, R, name, s["gn_iter"], s["beta"])
        row["min_coefficient"] = float(Hl.min())
        row["negative_coefficients"] = int(np.sum(Hl < 0))
        rows[name] = row
    checks = {}
    for qp_solver in ("osqp", "clarabel"):
        a, b = rows.get(solvers.qp_solver_name(qp_solver)), rows.get(solvers.qp_solver_name(qp_solver, "nonneg"))
        if a and b:
            checks[solvers.qp_solver_name(qp_solver, "nonneg")] = {
                "all_coefficients_nonneg": b["min_coefficient"] >= 0.0,
                "deviation_no_worse_than_unconstrained": b["mean_deviation"] <= a["mean_deviation"],
                "deviation_ratio_vs_unconstrained": b["mean_deviation"] / max(a["mean_deviation"], 1e-300),
            }
    return {"setting": {"coefficients": "half-normal |N(0, 1)|", "gn_steps": s["gn_iter"]}, "solvers": rows, "acceptance": checks}


def _part_sparse(mdp, s, rng, D):
    tasks = _tasks(mdp, s, rng, D, s["transfer_tasks"], s["transfer_demos"], kind="nonneg", sparsity=s["sparsity"])
    R, demos, H = tasks.rewards, tasks.demos, tasks.coefficients
    out = {}
    for name in _gn_names("sparse"):
        sweep = []
        for alpha in s["alphas"]:
            row, Hl = _transfer(mdp, D, demos, R, name, s["sparse_gn_iter"], s["beta"], alpha=float(alpha))
            sweep.append(
                {
                    "alpha": float(alpha),
                    "exact_zeros": int(np.sum(Hl == 0.0)),
                    "zero_fraction": float(np.mean(Hl == 0.0)),
                    "final_loss": row["final_loss"],
                    "final_objective": row["final_objective"],
                    "mean_deviation": row["mean_deviation"],
                    "q_evaluations": row["q_evaluations"],
                }
            )
        zeros = [r["exact_zeros"] for r in sweep]
        out[name] = {"sweep": sweep, "zeros_nondecreasing_in_alpha": zeros == sorted(zeros), "zeros_grow": zeros[-1] > zeros[0]}
    return {
        "setting": {
            "coefficients": f"half-normal, each zero with probability {s['sparsity']}",
            "true_zeros": int(np.sum(H == 0.0)),
            "coefficients_total": int(H.size),
            "gn_steps": s["sparse_gn_iter"],
        },
        "variants": out,
    }


def _gn_data(mdp, s, rng, D, n_steps):
    """Realistic block-QP data: the reduced subproblems of successive GN steps of a transfer.

    Returns a list of ``n_steps`` pairs ``(R (n, k, k), b (n, k))``, one per LM step (the data
    a real H-step hands to the QP, changing from one solve to the next).
    """
    from solvers.gauss_newton import reduce_least_squares

    mu, pi_hat = empirical_statistics(mdp, _tasks(mdp, s, rng, D, s["transfer_tasks"], s["transfer_demos"]).demos)
    problem = weights_problem(PolicyMatchingObjective(mdp, mu, pi_hat, s["beta"]), D)
    solver = solvers.get_solver("gn-qp-osqp")
    x = np.zeros((problem.n_rows, problem.n_params))
    state = solver.init_state(problem, x)
    data = []
    for _ in range(n_steps):
        data.append(reduce_least_squares(state.jacobian, state.residual, x, state.lam))
        x, state, _ = solver.update(problem, x, state)
    return data


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _part_timing(mdp, s, rng, D):
    import cvxpy as cp

    from solvers.qp_cvxpy import CVXPY_NAMES, CvxpyBlockQP, qp_solver_options
    from solvers.qp_direct import DirectBlockQP

    reps = max(int(s["repeats"]), 1)
    variants = _gn_data(mdp, s, rng, D, reps + 1)  # each re-solve gets the next step's data
    Rf, b = variants[0]
    n, k = b.shape
    out = {"tasks": n, "k": k, "repeats": reps, "routes": {}}
    for constraint in ("none", "nonneg", "sparse"):
        t0 = time.perf_counter()
        cv = CvxpyBlockQP(n, k, constraint)
        build = time.perf_counter() - t0
        di = DirectBlockQP(n, k, constraint)
        for qp_solver in ("osqp", "clarabel"):
            if solvers.qp_solver_name(qp_solver) not in solvers.available_solvers():
                continue
            t0 = time.perf_counter()
            first = cv.solve(*variants[0], qp_solver, alpha=0.05)  # canonicalisation happens here
            compile_time = time.perf_counter() - t0 + build
            di.solve(*variants[0], qp_solver, alpha=0.05)
            it = iter(variants[1:])
            t_cv = _median_time(lambda: cv.solve(*next(it), qp_solver, alpha=0.05), reps)
            it = iter(variants[1:])
            t_di = _median_time(lambda: di.solve(*next(it), qp_solver, alpha=0.05), reps)
            a, d = cv.solve(*variants[0], qp_solver, alpha=0.05), di.solve(*variants[0], qp_solver, alpha=0.05)
            out["routes"][f"{constraint}/{qp_solver}"] = {
                "cvxpy_block_dpp_per_task_us": 1e6 * t_cv / n,
                "direct_qp_solver_per_task_us": 1e6 * t_di / n,
                "ratio_cvxpy_over_direct": t_cv / t_di,
                "cvxpy_compile_and_first_solve_s": compile_time,
                "max_abs_difference": float(np.max(np.abs(a.z - d.z))),
                "status": [first.status, a.status, d.status],
                "within_10x_of_direct": t_cv <= 10 * t_di,
                "under_0.5ms_per_task": t_cv / n < 5e-4,
            }
    # scale: a fresh cp.Problem per task per step (what the block DPP form avoids)
    m = min(int(s["fresh_tasks"]), n)
    if m > 0:
        t0 = time.perf_counter()
        for i in range(m):
            z = cp.Variable(k)
            cp.Problem(cp.Minimize(cp.sum_squares(Rf[i] @ z - b[i]))).solve(solver=CVXPY_NAMES["osqp"], **qp_solver_options("osqp"))
        out["fresh_cp_problem_per_task_us"] = {"none/osqp": 1e6 * (time.perf_counter() - t0) / m, "tasks_timed": m}
    return out


def run(args):
    """Run the selected parts; returns the JSON-serialisable measurements."""
    s = resolve_settings(args, DEFAULTS, QUICK)
    mdp = GridWorld(size=s["size"])
    seeds = np.random.SeedSequence(s["seed"]).spawn(6)
    D = random_dictionary(mdp.n_params, s["n_primitives"], np.random.default_rng(seeds[0]))
    parts = dict(zip(PARTS, (_part_transfer, _part_fit, _part_nonneg, _part_sparse, _part_timing)))
    out = {
        "benchmark": "solvers",
        "settings": {k: v for k, v in s.items() if k != "parts"},
        "available_solvers": solvers.available_solvers(),
        "blas_threads_env": {v: os.environ.get(v) for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")},
    }
    for i, name in enumerate(parts, start=1):
        if name in s["parts"]:
            t0 = time.perf_counter()
            out[name] = parts[name](mdp, s, np.random.default_rng(seeds[i]), D)
            out[name]["part_wall_time_s"] = time.perf_counter() - t0
    return out
