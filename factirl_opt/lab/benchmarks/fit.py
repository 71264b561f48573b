"""Time fitting the paper-scale training set: flat (GradIRL) for all tasks, then factorial with
every combination of H-step and D-step solvers, side by side in one run.

Paper-scale defaults (the paper's section 4; docs/maths.md §9): 10x10 grid, 100 tasks whose rewards mix
k = 5 random primitives (:func:`factirl_opt.synthetic_tasks`: D ~ N(0, 1), H ~ N(0, 1)), 10
demonstrations of 10 steps per task, beta = 5. The flat learner fits every task (batched);
the factorial learner (``init="pca"``) starts from the PCA of those flat rewards (passed as
``flat_rewards``, so the flat fit is not repeated) and is fitted once per combination of
``--h-solvers`` x ``--d-solvers`` (default (armijo | gn-qp-clarabel) x (armijo | lbfgs |
gn-cg)), every fit from the same start. Both learners use their default hyperparameters unless
overridden.

Prints, for the flat learner and for each combination: wall time, Q* evaluations, linear
solves, outer iterations, status and stop reason, final loss and the mean train deviation from
the optimal score (eq. 13). ``factorial`` is the combination ``--h-solver`` | ``--d-solver``
(the one the earlier versions of this benchmark printed); ``reference`` is armijo | armijo (the
paper's); ``best`` is the combination with the fewest Q* evaluations among those whose final
loss is at most the reference's and whose train deviation is at most 5% above it.

*Linear solves* count the ``S x S`` Bellman systems ``(I - gamma P_pi) x = b`` solved for one
task (any number of right-hand sides): each sweep of policy iteration inside a Q* evaluation,
each adjoint solve of a gradient, each Jacobian-vector product of ``gn-cg`` and each Jacobian of
the QP H-step. They are counted by a planner that wraps the default one
(:class:`CountingPlanner`), so they measure the work Q* evaluations do not show.

``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
"""

import time

import numpy as np

import solvers

from ...parallel import limit_blas_threads
from ...evaluation import deviation
from ...exceptions import ValidationError
from ...learners.start import Start
from ...objectives.sharding import Execution
from ...learners.factirl import FactIRL
from ...learners.gradirl import GradIRL
from ...mdp.tabular import GridWorld
from ...planning import CountingPlanner, get_planner
from ...learners.solver_settings import SolverSettings
from ...datasets.synthetic import synthetic_tasks
from ..arguments import integer, real, solver_name
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run"]

DEFAULTS = {"size": 10, "n_tasks": 100, "n_demos": 10, "length": 10, "n_primitives": 5, "beta": 5.0,
            "flat_max_iter": 100, "max_iter": 100, "inner_steps": 5, "tol": 1e-5, "h_solver": "armijo",
            "d_solver": "armijo", "h_solvers": ["armijo", "gn-qp-clarabel"], "d_solvers": ["armijo", "lbfgs", "gn-cg"],
            "seed": 0, "blas_threads": 1}
#: a few seconds' setting in which the factorial learner still clearly beats the flat one (k = 2 primitives
#: shared by 16 tasks: measured deviation ratio 0.1-0.4 over seeds 0-5)
QUICK = {"size": 4, "n_tasks": 16, "n_demos": 5, "length": 6, "n_primitives": 2, "max_iter": 15, "flat_max_iter": 20}
#: the paper's combination, against which the others are compared
REFERENCE = ("armijo", "armijo")
#: a combination qualifies for ``best`` if its train deviation is at most this factor times the reference's
DEVIATION_SLACK = 1.05


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--size", type=integer(2), help="grid side")
    opt("--n-tasks", type=integer(1), help="training tasks")
    opt("--n-demos", type=integer(1), help="demonstrations per task")
    opt("--length", type=integer(1), help="steps per demonstration")
    opt("-k", "--n-primitives", type=integer(1), help="primitives, true and learnt")
    opt("--beta", type=real(0, low_open=True), help="Boltzmann inverse temperature")
    opt("--flat-max-iter", type=integer(0), help="GradIRL iterations")
    opt("--max-iter", type=integer(0), help="FactIRL outer iterations")
    opt("--inner-steps", type=integer(1), help="FactIRL steps per sub-problem")
    opt("--tol", type=real(0), help="relative-decrease stopping tolerance (both learners)")
    opt("--h-solver", type=solver_name, help="H-step solver of the 'factorial' entry")
    opt("--d-solver", type=solver_name, help="D-step solver of the 'factorial' entry")
    opt("--h-solvers", type=solver_name, nargs="+", metavar="NAME", help="H-step solvers compared")
    opt("--d-solvers", type=solver_name, nargs="+", metavar="NAME", help="D-step solvers compared (with each H-step solver)")
    opt("--seed", type=integer(0), help="seed of the synthetic tasks")
    opt("--blas-threads", type=integer(0), help="OpenBLAS threads (0: leave as is)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny configuration for tests; options given explicitly keep their value")


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _entry(learner, planner, elapsed, mdp, true_rewards):
    """The measurements of a fitted learner."""
    return {
        "time_s": elapsed, "n_evaluations": int(learner.n_evaluations_), "n_linear_solves": int(planner.n_solves),
        "n_iter": int(learner.n_iter_), "status": learner.status_, "final_loss": float(learner.loss_.sum()),
        "mean_train_deviation": float(np.mean(deviation(mdp, true_rewards, learner.rewards_))),
    }


def _fit_factorial(s, mdp, tasks, flat, settings):
    """One factorial fit with the solver ``settings`` from the PCA of the flat rewards (the paper's
    start, unshrunk: every combination starts from the same point), with its own counting planner."""
    planner = CountingPlanner(get_planner(mdp))
    fact = FactIRL(n_primitives=s["n_primitives"], beta=s["beta"], start=Start(init="pca", pca_shrink=False),
                   max_iter=s["max_iter"], inner_steps=s["inner_steps"], tol=s["tol"], execution=Execution(planner=planner),
                   rng=np.random.default_rng(s["seed"] + 1),
                   **settings.learner_kwargs())
    _, elapsed = _timed(lambda: fact.fit(mdp, tasks.demos, flat_rewards=flat.rewards_))
    entry = _entry(fact, planner, elapsed, mdp, tasks.rewards)
    entry.update(h_solver=settings.h_solver, d_solver=settings.d_solver, stop_reason=fact.stop_reason_)
    return entry


def _combinations(s):
    """The (H, D) pairs to fit (the reference and the 'factorial' pair included) and those skipped.

    Raises
    ------
    ValidationError
        When a name is not registered, or the 'factorial' pair needs a solver whose modules are not installed.
    """
    wanted = [(h, d) for h in s["h_solvers"] for d in s["d_solvers"]]
    for pair in (REFERENCE, (s["h_solver"], s["d_solver"])):
        if pair not in wanted:
            wanted.append(pair)
    unknown = sorted({n for pair in wanted for n in pair} - set(solvers.registered_solvers()))
    if unknown:
        raise ValidationError(f"bench fit: unknown solver(s) {', '.join(unknown)}; available: {', '.join(solvers.available_solvers())}")
    available = set(solvers.available_solvers())
    if not {s["h_solver"], s["d_solver"]} <= available:
        raise ValidationError(f"bench fit: the 'factorial' pair {s['h_solver']}|{s['d_solver']} needs a solver whose modules "
                              f"are not installed; available: {', '.join(sorted(available))}")
    keep = [(h, d) for h, d in wanted if h in available and d in available]
    return keep, [f"{h}|{d}" for h, d in wanted if (h, d) not in keep]


def _fit_all(s, pairs):
    """Generate the tasks, fit flat, then every pair; returns the measurements."""
    mdp = GridWorld(size=s["size"])
    tasks, t_data = _timed(lambda: synthetic_tasks(mdp, s["n_tasks"], s["n_demos"], s["length"],
                                                   n_primitives=s["n_primitives"], rng=np.random.default_rng(s["seed"])))
    planner = CountingPlanner(get_planner(mdp))
    flat, t_flat = _timed(lambda: GradIRL(beta=s["beta"], max_iter=s["flat_max_iter"], tol=s["tol"], gtol=0.0, stol=0.0,  # as in the committed runs
                                          execution=Execution(planner=planner)).fit(mdp, tasks.demos))
    flat_entry = _entry(flat, planner, t_flat, mdp, tasks.rewards)
    combos = {f"{h}|{d}": _fit_factorial(s, mdp, tasks, flat, SolverSettings(h, d_solver=d)) for h, d in pairs}
    return flat_entry, combos, t_data


def _compare(combos, flat):
    """Ratios to the reference and to the flat learner; the best qualifying combination."""
    ref = combos.get("|".join(REFERENCE))
    for entry in combos.values():
        dev = entry["mean_train_deviation"]
        entry["deviation_ratio_over_flat"] = dev / flat["mean_train_deviation"] if flat["mean_train_deviation"] > 0 else float("nan")
        if ref is not None:
            entry["evaluations_ratio_vs_reference"] = entry["n_evaluations"] / max(ref["n_evaluations"], 1)
            entry["linear_solves_ratio_vs_reference"] = entry["n_linear_solves"] / max(ref["n_linear_solves"], 1)
            entry["qualifies"] = bool(entry["final_loss"] <= ref["final_loss"]
                                      and dev <= DEVIATION_SLACK * ref["mean_train_deviation"])
    qualified = [k for k, e in combos.items() if e.get("qualifies")]
    return min(qualified, key=lambda k: (combos[k]["n_evaluations"], combos[k]["time_s"])) if qualified else None


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    pairs, skipped = _combinations(s)
    with limit_blas_threads(s["blas_threads"]) as threads:
        flat, combos, t_data = _fit_all(s, pairs)
    best = _compare(combos, flat)
    fact = combos[f"{s['h_solver']}|{s['d_solver']}"]
    dev_flat, dev_fact = flat["mean_train_deviation"], fact["mean_train_deviation"]
    settings = {key: s[key] for key in DEFAULTS}
    settings.update(quick=bool(s["quick"]), blas_threads=threads)
    return {
        "benchmark": "fit",
        "total_s": flat["time_s"] + fact["time_s"],
        "flat": flat,
        "factorial": fact,
        "deviation_ratio_factorial_over_flat": dev_fact / dev_flat if dev_flat > 0 else float("nan"),
        "combinations": combos,
        "reference": "|".join(REFERENCE),
        "best": best,
        "skipped": skipped,
        "data_time_s": t_data,
        "settings": settings,
    }
