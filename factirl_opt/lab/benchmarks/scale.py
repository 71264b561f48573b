"""Planning at scale: grid worlds up to 100x100 (S = 10,000) with 100 tasks, planner by planner.

For every grid side in ``--sizes`` (default 10 20 32 64 100) and ``--tasks`` tasks (default
100) whose rewards mix 5 random primitives (``factirl_opt.datasets.synthetic``), in this order:

- ``build_s``: ``GridWorld(size)`` (sparse dynamics);
- ``demonstrations_s``: ``sample_demonstrations`` (``--n-demos`` x ``--length``) and their
  empirical statistics, default planner (``Q*`` from scratch);
- per planner, ``dense`` (only up to ``--dense-max-states`` states, else skipped with the
  reason) and ``sparse-lu``: ``cold_plan_s``, ``Q*`` and the greedy policy by policy iteration
  from scratch at the learner's current estimate ``R_hat = R + 0.5 N(0, 1)`` (the warm-up;
  factorisation caches emptied first), then warm batched loss+gradient evaluations of eq. (5)
  (``policy_matching_loss`` with that greedy policy passed as ``policy=``):

  * ``warm_s`` (the headline: the greedy policy already known): at ``R_hat`` itself. One
    policy evaluation and one adjoint solve per task; the dense planner factorises for both,
    the sparse one reuses the factorisations cached by the warm-up (solves only);
  * ``warm_perturbed_s``: at slightly perturbed rewards ``R_hat + 1e-3 N(0, 1)`` (a fresh
    perturbation per repeat), as in a line search: the greedy policy changes in a few states
    of some tasks (``changed_tasks``, ``max_changed_states``, for the first perturbation),
    which then need a second, low-rank-updated evaluation. The same perturbation flips more
    states in a larger world, so this figure also grows with the work.

  Each is the best of ``--repeats`` runs (one run when the first exceeds ``--budget`` s), the
  repeats interleaved across planners so that load changes on a shared machine hit them alike.
  ``auto``, the default, is not a planner of its own but a name that resolves to one of them
  (``default_resolves_to``); its entry is that planner's (``same_as``);
- ``score_s``: ``deviation`` (eq. 13) of ``R_hat`` on the true rewards, default planner,
  caches emptied first.

Also per size: the planners' gradients at the first perturbation, compared with the first
planner's (``grad_max_rel_diff``), and ``peak_rss_mb``, the peak resident memory
(``ru_maxrss``) of the process that measured that size. By default each size runs in a fresh
(spawned) process, so that figure is the size's own peak, SuperLU's C allocations included
(tracemalloc would miss them); ``--in-process`` runs all sizes here (the peak so far).

Summary: ``ratio_dense_over_default`` (``warm_s``) per size where dense ran, the default
planner's fitted exponent ``warm_s ~ S^e`` (log-log least squares over the sizes >=
``--fit-min-size``, default 32), the same two for ``warm_perturbed_s`` (``..._perturbed``), and the load average before and after the run (the timings
are wall times on a possibly shared machine). ``--plot PATH`` writes a log-log figure
(matplotlib, Agg backend). BLAS threads are limited to ``--blas-threads`` (default 1).

Fits (``--fit-iter N``, instead of the planner timings): per size, an Objectworld of that side
(5 inner and 2 outer colours, object density 0.05) with ``--tasks`` tasks
(``multitask_rewards``) and their demonstrations (``--n-demos`` x ``--length``, sampled 100 tasks
at a time), then a FactIRL fit on the world's features (``objectworld_features``) for N outer
iterations: random start, Gauss-Newton QP H-steps (Clarabel), L-BFGS D-steps, 2 inner steps,
no stopping rule before N (``tol=0``, ``gtol=0``), under the planning budget ``--max-bytes``
(:mod:`factirl_opt.planning.budget`; default none). Reported per size: ``build_s``,
``demonstrations_s``, ``fit_s``, ``fit_s_per_iter``, ``n_iter``, ``n_evaluations``,
``loss_history``, ``planning_bytes_per_task`` (the budget's estimate for a Jacobian),
``tasks_per_chunk`` (of the H-step's Jacobians and of the gradients; ``--tasks`` when all
fit), ``peak_rss_before_fit_mb`` (the world and the demonstrations: ``ru_maxrss`` before the
fit) and ``peak_rss_mb`` (after it); and
``peak_rss_summed_mb``, the peaks of this process and of the size's process added (a sum over
processes, not the peak of one). ``--max-bytes`` applies to fits only.

Fits side by side (``--fit-iter N --jobs J [J ...]`` and/or ``--dask``): the same fit per size for
each ``FactIRL(n_jobs=J)`` and on a 2-worker dask ``LocalCluster``, ``--repeats`` rounds in this
one process, with wall times, medians, speed-ups, CPU, bytes sent to the shards and the learnt
arrays' differences: :mod:`factirl_opt.lab.benchmarks.scale_jobs`.

Evaluations (``--evaluations --tasks N [N ...]``, with ``--jobs`` and/or ``--dask``): per size and
number of tasks, the fits' problem, then one policy-matching evaluation's time and peak memory
(summed over the processes involved) per configuration, and the growth exponents against tasks
and states: :mod:`factirl_opt.lab.benchmarks.scale_evaluations`.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import os
import resource
import time

import numpy as np

from ...parallel import limit_blas_threads
from ...tasks.demonstrations import empirical_statistics, sample_demonstrations
from ...evaluation import deviation
from ...exceptions import ValidationError
from ...learners.factirl import FactIRL
from ...files import atomic_write
from ...mdp.tabular import GridWorld
from ...objectives import policy_matching_loss
from ...datasets.objectworld import make_objectworld, multitask_rewards, objectworld_features, state_action_rewards
from ...planning import AUTO_DENSE_MAX_STATES, clear_caches, get_planner, optimal_q, planning_budget
from ...planning.budget import check_max_bytes, chunk_size, task_bytes
from ...datasets.synthetic import random_coefficients, random_dictionary
from ...tasks.features import task_rewards
from ..arguments import count, integer, real, text
from .scale_evaluations import run_evaluations
from .scale_jobs import check_jobs, run_side_by_side as _side_by_side

__all__ = ["add_arguments", "run"]

DEFAULT_PLANNER = "auto"


def add_arguments(parser):
    parser.add_argument("--sizes", type=integer(2), nargs="+", default=[10, 20, 32, 64, 100], help="grid sides (default: 10 20 32 64 100)")
    parser.add_argument("--tasks", type=integer(1), nargs="+", default=[100],
                        help="tasks (default 100); several values only with --evaluations")
    parser.add_argument("--n-demos", type=integer(1), default=10, help="demonstrations per task (default 10)")
    parser.add_argument("--length", type=integer(1), default=10, help="steps per demonstration (default 10)")
    parser.add_argument("--beta", type=real(0, low_open=True), default=5.0)
    parser.add_argument("--repeats", type=integer(1), default=3, help="timed runs of each warm evaluation, best kept (default 3)")
    parser.add_argument("--budget", type=real(0), default=5.0, help="an evaluation whose first run takes longer is run once (s)")
    parser.add_argument("--dense-max-states", type=integer(0), default=1024,
                        help="run the dense planner only up to this many states (default 1024: at S = 4096 its (S, A, S) "
                             "transitions alone take 512 MiB and 100 tasks' 4096 x 4096 LUs take minutes)")
    parser.add_argument("--fit-min-size", type=integer(1), default=32, help="fit the exponent over sizes >= this (default 32)")
    parser.add_argument("--in-process", action="store_true", help="measure every size in this process (no fresh process per size)")
    parser.add_argument("--plot", type=text("a path for the plot"), default=None, metavar="PATH", help="write a log-log plot of the timings to PATH")
    parser.add_argument("--seed", type=integer(0), default=0)
    parser.add_argument("--blas-threads", type=integer(0), default=1, help="OpenBLAS threads (0: leave as is; default 1)")
    parser.add_argument("--fit-iter", type=integer(0), default=0, metavar="N",
                        help="instead of the planner timings, fit FactIRL on an Objectworld's features for N outer "
                             "iterations per size (default 0: timings)")
    parser.add_argument("--max-bytes", type=count(1), default=None,
                        help="planning memory budget of the fits in bytes, e.g. 16e9 (default: none)")
    parser.add_argument("--jobs", type=integer(1, also=(-1,), note=" (or -1: every core)"), nargs="+", default=None, metavar="J",
                        help="with --fit-iter: the same fit side by side for each FactIRL n_jobs J (positive or -1), "
                             "in this process, --repeats times alternating (default: one fit, n_jobs=1)")
    parser.add_argument("--dask", action="store_true",
                        help="with --fit-iter: also the fit on a 2-worker dask LocalCluster (needs the dask extra)")
    parser.add_argument("--evaluations", action="store_true",
                        help="instead of the planner timings, one objective evaluation's time and peak memory per size, "
                             "number of --tasks and configuration (--jobs, --dask), with growth exponents")


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def _perturbed(R_hat, seed, r):
    """The r-th perturbation ``R_hat + 1e-3 N(0, 1)`` (regenerated, not stored: 32 MB each at 100x100)."""
    return R_hat + 1e-3 * np.random.default_rng([seed, r]).standard_normal(R_hat.shape)


def _planner_timings(mdp, names, R_hat, mu, pi_hat, args, seed):
    """Cold plan of each planner, then its warm evaluations (repeats interleaved across planners,
    so that load changes hit them alike). Returns {name: entry} and the gradients' differences."""
    clear_caches(mdp)
    cold, pols = {}, {}
    for name in names:
        cold[name], (_, pols[name]) = _timed(lambda: optimal_q(mdp, R_hat, planner=name))
    times = {name: {"warm_s": [], "warm_perturbed_s": []} for name in names}
    ref, diffs = None, {}
    for key in ("warm_s", "warm_perturbed_s"):
        for r in range(max(1, args.repeats)):
            rewards = _perturbed(R_hat, seed, r) if key == "warm_perturbed_s" else R_hat
            for name in names:
                if r and times[name][key][0] > args.budget:
                    continue
                t, (_, grad) = _timed(lambda: policy_matching_loss(mdp, rewards, mu, pi_hat, args.beta,
                                                                   policy=pols[name], planner=name))
                times[name][key].append(t)
                if key == "warm_s" and r == 0:  # the planners' gradients agree
                    ref = grad if ref is None else ref
                    diffs[name] = float(np.max(np.abs(grad - ref)) / np.max(np.abs(ref)))
    entries = {name: {"resolved": name, "cold_plan_s": cold[name], "warm_s": min(times[name]["warm_s"]),
                      "warm_perturbed_s": min(times[name]["warm_perturbed_s"]), "runs": len(times[name]["warm_s"])}
               for name in names}
    return entries, diffs, pols


def _one_size(size, args):
    """Every measurement at one grid size (see the module docstring)."""
    with limit_blas_threads(args.blas_threads):
        rng = np.random.default_rng([args.seed, size])
        t_build, mdp = _timed(lambda: GridWorld(size))
        S, A = mdp.n_states, mdp.n_actions
        R = task_rewards(random_dictionary(mdp.n_params, 5, rng), random_coefficients(args.tasks, 5, rng=rng), S, A)
        t_demos, (mu, pi_hat) = _timed(
            lambda: empirical_statistics(mdp, sample_demonstrations(mdp, R, args.n_demos, args.length, rng)))
        R_hat = R + 0.5 * rng.standard_normal(R.shape)
        seed = int(rng.integers(2**31))
        names = ["sparse-lu"] if S > args.dense_max_states else ["dense", "sparse-lu"]
        planners, diffs, pols = _planner_timings(mdp, names, R_hat, mu, pi_hat, args, seed)
        resolved = get_planner(mdp, DEFAULT_PLANNER).name
        planners[DEFAULT_PLANNER] = dict(planners[resolved], resolved=resolved, same_as=resolved)
        if "dense" not in names:
            planners["dense"] = {"skipped": f"S = {S} > --dense-max-states {args.dense_max_states}"}
        # greedy policies after the first perturbation (warm: cheap)
        changes = (optimal_q(mdp, _perturbed(R_hat, seed, 0), policy=pols["sparse-lu"], planner="sparse-lu")[1]
                   != pols["sparse-lu"]).sum(axis=1)
        clear_caches(mdp)
        t_score, _ = _timed(lambda: deviation(mdp, R, R_hat))
    return {
        "n_states": S,
        "n_actions": A,
        "default_resolves_to": resolved,
        "build_s": t_build,
        "demonstrations_s": t_demos,
        "score_s": t_score,
        "planners": {name: planners[name] for name in ("dense", "sparse-lu", DEFAULT_PLANNER)},
        "changed_tasks": int(np.count_nonzero(changes)),
        "max_changed_states": int(changes.max()),
        "grad_max_rel_diff": diffs,
        "peak_rss_mb": _peak_rss_mb(),
    }


#: tasks sampled at once by the fits' demonstrations (their planning is not budgeted)
DEMO_CHUNK = 100
#: the fits' primitives and solvers (the Objectworld presets' FactIRL on features, from a random start)
FIT_OPTIONS = dict(n_primitives=5, init="random", solver="gn-qp-clarabel", d_solver="lbfgs", inner_steps=2,
                   tol=0.0, gtol=0.0)


def fit_problem(size: int, args: argparse.Namespace) -> dict:
    """The fits' Objectworld of side ``size``, its demonstrations and features (see the module docstring).

    Returns
    -------
    dict
        ``mdp``, ``demos`` (per task), ``features`` (S, F), ``build_s`` and ``demonstrations_s``;
        the MDP's planning caches emptied.
    """
    rng = np.random.default_rng([args.seed, size])
    t_build, world = _timed(lambda: make_objectworld(size, 5, 2, 0.05, rng=rng))
    mdp = world.mdp()
    R = state_action_rewards(multitask_rewards(world, args.tasks, rng=rng)[0], mdp.n_actions)

    def demos():
        out = []
        for lo in range(0, args.tasks, DEMO_CHUNK):
            out += sample_demonstrations(mdp, R[lo:lo + DEMO_CHUNK], args.n_demos, args.length, rng)
        return out

    t_demos, demos_per_task = _timed(demos)
    del R
    clear_caches(mdp)
    return {"mdp": mdp, "demos": demos_per_task, "features": objectworld_features(world), "build_s": t_build,
            "demonstrations_s": t_demos}


def fit_model(args: argparse.Namespace, features: np.ndarray, **extra) -> FactIRL:
    """The fits' FactIRL (``FIT_OPTIONS``, ``--fit-iter`` outer iterations) on ``features``; ``extra``:
    more keyword arguments (``n_jobs``, ``backend``, ``client``, or overrides such as ``max_iter``)."""
    options = dict(beta=args.beta, max_iter=args.fit_iter, features=features, rng=args.seed, **FIT_OPTIONS)
    options.update(extra)
    return FactIRL(**options)


def _one_fit(size, args):
    """A FactIRL fit on an Objectworld of side ``size`` (see the module docstring)."""
    with limit_blas_threads(args.blas_threads):
        problem = fit_problem(size, args)
        mdp, demos_per_task, features = problem["mdp"], problem["demos"], problem["features"]
        t_build, t_demos = problem["build_s"], problem["demonstrations_s"]
        before = _peak_rss_mb()
        model = fit_model(args, features)
        with planning_budget(args.max_bytes):
            t_fit, _ = _timed(lambda: model.fit(mdp, demos_per_task))
        planner = get_planner(mdp)
        chunks = {what: chunk_size(args.tasks, task_bytes(planner, d), args.max_bytes)
                  for what, d in (("jacobian", FIT_OPTIONS["n_primitives"]), ("gradient", 0))}
    return {
        "n_states": mdp.n_states, "n_actions": mdp.n_actions, "n_features": int(features.shape[1]),
        "build_s": t_build, "demonstrations_s": t_demos, "fit_s": t_fit, "fit_s_per_iter": t_fit / max(1, model.n_iter_),
        "n_iter": model.n_iter_, "n_evaluations": model.n_evaluations_, "status": model.status_,
        "loss_history": [float(v) for v in model.loss_history_],
        "planning_bytes_per_task": task_bytes(planner, FIT_OPTIONS["n_primitives"]), "tasks_per_chunk": chunks,
        "peak_rss_before_fit_mb": before, "peak_rss_mb": _peak_rss_mb(),
    }


def _peak_rss_mb():
    """This process's peak resident memory (MiB; ``ru_maxrss`` is in KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0


def _fit_exponent(per_size, min_size, key="warm_s"):
    """Least-squares slope of log(``key`` of the default planner) against log(S) over sizes >= min_size."""
    pts = [(e["n_states"], e["planners"][DEFAULT_PLANNER][key]) for name, e in per_size.items()
           if int(name.split("x")[0]) >= min_size]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def _ratios(per_size, key):
    return {name: e["planners"]["dense"][key] / e["planners"][DEFAULT_PLANNER][key]
            for name, e in per_size.items() if key in e["planners"]["dense"]}


def _plot(per_size, path, tasks):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    S = np.array([e["n_states"] for e in per_size.values()])
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name in ("dense", "sparse-lu"):
        for key, style, what in (("warm_s", "o-", "warm loss+gradient"), ("warm_perturbed_s", "o:", "perturbed")):
            pts = [(e["n_states"], e["planners"][name][key]) for e in per_size.values() if key in e["planners"][name]]
            if pts:
                ax.loglog(*zip(*pts), style, label=f"{name}: {what}")
    for key, label in (("demonstrations_s", "sample demonstrations"), ("score_s", "score (deviation)"), ("build_s", "build GridWorld")):
        ax.loglog(S, [e[key] for e in per_size.values()], "s--", alpha=0.6, label=label)
    ax.set_xlabel("states S")
    ax.set_ylabel("wall time (s)")
    ax.set_title(f"GridWorld, {tasks} tasks, one run (auto: dense up to {AUTO_DENSE_MAX_STATES} states)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fmt = os.path.splitext(os.fspath(path))[1].lstrip(".").lower() or "png"
    try:
        with atomic_write(path, binary=True) as fh:  # an interrupt or a full disk keeps the old figure
            fig.savefig(fh, format=fmt, dpi=120)
    finally:
        plt.close(fig)


def _measure_all(args, measure):
    if args.in_process:
        return {f"{s}x{s}": measure(s, args) for s in args.sizes}
    ctx = multiprocessing.get_context("spawn")
    per_size = {}
    plain = argparse.Namespace(**{k: v for k, v in vars(args).items() if not k.startswith("_")})
    for s in args.sizes:
        with ctx.Pool(1) as pool:  # a fresh process per size: its own peak memory
            per_size[f"{s}x{s}"] = pool.apply(measure, (s, plain))
    return per_size


def _check_fit_args(args):
    """Validated ``--fit-iter``, ``--tasks``, ``--jobs``, ``--evaluations`` and ``--max-bytes`` (ValidationError
    naming the value); ``args.tasks`` made an int except with ``--evaluations``."""
    if isinstance(args.fit_iter, bool) or not isinstance(args.fit_iter, int) or args.fit_iter < 0:
        raise ValidationError(f"--fit-iter must be an integer >= 0; got {args.fit_iter!r}")
    evaluations = getattr(args, "evaluations", False)
    if evaluations and args.fit_iter:
        raise ValidationError(f"--evaluations and --fit-iter {args.fit_iter} are separate modes: give one")
    if args.max_bytes is not None and not (args.fit_iter or evaluations):
        raise ValidationError(f"--max-bytes {args.max_bytes!r} applies to fits only (or --evaluations): give --fit-iter N too")
    max_bytes = check_max_bytes(args.max_bytes, "--max-bytes")
    tasks = list(args.tasks) if isinstance(args.tasks, (list, tuple)) else [args.tasks]
    for n in tasks:
        if n < 1:
            raise ValidationError(f"--tasks must be >= 1; got {n!r}")
    if len(set(tasks)) != len(tasks) or (len(tasks) > 1 and not evaluations):
        raise ValidationError(f"--tasks takes several distinct values with --evaluations only; got {tasks}")
    args.tasks = tasks if evaluations else tasks[0]
    if (args.jobs or args.dask) and not (args.fit_iter or evaluations):
        raise ValidationError("--jobs and --dask apply to fits only (or --evaluations): give --fit-iter N too")
    if args.jobs is not None:
        check_jobs(args.jobs)
    return max_bytes


def run_fits(args):
    """The ``--fit-iter`` mode: one FactIRL fit per size (see the module docstring)."""
    load_before = os.getloadavg()
    per_size = _measure_all(args, _one_fit)
    own = _peak_rss_mb()
    return {
        "benchmark": "scale",
        "mode": "fit",
        "sizes": per_size,
        "peak_rss_summed_mb": {name: own + (0.0 if args.in_process else e["peak_rss_mb"]) for name, e in per_size.items()},
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "settings": {
            "sizes": list(args.sizes), "tasks": args.tasks, "n_demos": args.n_demos, "length": args.length,
            "beta": args.beta, "fit_iter": args.fit_iter, "max_bytes": args.max_bytes, "seed": args.seed,
            "blas_threads": args.blas_threads, "fit": {k: v for k, v in FIT_OPTIONS.items()},
            "world": "make_objectworld(size, 5, 2, 0.05), multitask_rewards, objectworld_features",
            "memory": "ru_maxrss of the process that measured the size"
                      + (" (this process: the peak so far)" if args.in_process else " (a fresh process per size)"),
        },
    }


def run_side_by_side(args):
    """The ``--fit-iter N --jobs J [J ...] [--dask]`` mode: the same fit side by side per n_jobs and on a
    2-worker dask cluster, in this process (:mod:`factirl_opt.lab.benchmarks.scale_jobs`)."""
    return _side_by_side(args, fit_problem, fit_model)


def run(args):
    args.max_bytes = _check_fit_args(args)
    if getattr(args, "evaluations", False):
        return run_evaluations(args, fit_problem)
    if args.fit_iter and (args.jobs or args.dask):
        return run_side_by_side(args)
    if args.fit_iter:
        return run_fits(args)
    load_before = os.getloadavg()
    per_size = _measure_all(args, _one_size)
    if args.plot:
        _plot(per_size, args.plot, args.tasks)
    return {
        "benchmark": "scale",
        "default_planner": DEFAULT_PLANNER,
        "sizes": per_size,
        "ratio_dense_over_default": _ratios(per_size, "warm_s"),
        "ratio_dense_over_default_perturbed": _ratios(per_size, "warm_perturbed_s"),
        "exponent_default": _fit_exponent(per_size, args.fit_min_size),
        "exponent_default_perturbed": _fit_exponent(per_size, args.fit_min_size, "warm_perturbed_s"),
        "exponent_sizes": [s for s in args.sizes if s >= args.fit_min_size],
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "settings": {
            "sizes": list(args.sizes),
            "tasks": args.tasks,
            "n_demos": args.n_demos,
            "length": args.length,
            "beta": args.beta,
            "repeats": args.repeats,
            "budget": args.budget,
            "dense_max_states": args.dense_max_states,
            "fit_min_size": args.fit_min_size,
            "seed": args.seed,
            "blas_threads": args.blas_threads,
            "memory": "ru_maxrss of the process that measured the size"
                      + (" (this process: the peak so far)" if args.in_process else " (a fresh process per size)"),
            "warm": "policy_matching_loss with the greedy policy of R_hat passed (after a cold warm-up); warm_s at R_hat, "
                    "warm_perturbed_s at R_hat + 1e-3 N(0, 1) (fresh noise per repeat); best of repeats",
            "plot": args.plot,
        },
    }
