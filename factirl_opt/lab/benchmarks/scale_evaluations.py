"""The scale benchmark's evaluations: one objective evaluation's time and memory against tasks and states.

``bench scale --evaluations --sizes S1 S2 ... --tasks N1 N2 ... [--jobs J ...] [--dask]``: for
every grid side and number of tasks, the world, demonstrations and features of the
``--fit-iter`` mode (:func:`factirl_opt.lab.benchmarks.scale.fit_problem`), the policy-matching
objective of those demonstrations (eq. 5, docs/maths.md §5) and feature rewards
``R_i = Phi D h_i`` (docs/maths.md §7, §8) from a random dictionary D (p, 5) and random
coefficients H (n, 5) (``factirl_opt.datasets.synthetic``); then, per configuration, in this process:

- ``n_jobs=J`` for each J of ``--jobs`` (default 1): the objective over J task shards
  (:func:`factirl_opt.objectives.sharding.sharded`, backend ``"processes"``; ``n_jobs=1`` is
  the objective itself);
- ``dask`` with ``--dask``: over the workers of a 2-worker ``LocalCluster``
  (:func:`factirl_opt.lab.benchmarks.scale_jobs.dask_client`, started once).

Per configuration: planning caches and the objective's warm starts emptied, then
``loss_and_grad`` once at ``R`` (``cold_s``: planning from scratch, and the shards' state built),
then ``--repeats`` warm calls, each at the rewards of freshly perturbed coefficients
``H + 1e-3 N(0, 1)`` (as in a line search; a call at the last rewards would be served from the
objective's last-point cache): ``warm_s`` (every call) and ``warm_median_s``. The cold call's
losses and feature gradients ``dJ/dw_i = Phi^T dJ/dR_i`` (n, p) are compared with the first
configuration's (``max_abs_diff``).

Memory: ``peak_rss_mb`` per process involved, the peak resident memory ``VmHWM`` of
``/proc/<pid>/status`` (Linux), reset before the configuration's first call by writing ``5``
to ``/proc/<pid>/clear_refs``: this process (the driver; ``"driver"``), and the shard
processes (read just before they stop) or the cluster's workers (read and reset in the
workers with ``client.run``; their nanny processes are not counted). ``peak_rss_summed_mb`` is
their sum (a sum of peaks, not the peak of a sum). Shard processes are forked where the
platform allows: each then counts, in its resident memory, pages it shares with the driver,
so the sum overstates; ``workers_uss_mb``, the shard processes' or workers' private memory
(psutil's USS) at the end, gives the part that is their own (None without psutil). Where a
peak cannot be reset (``peak_reset`` False) it is the process's peak so far; off Linux the
figures are None. A reset peak starts from the current resident memory, which includes the
problem and memory an earlier configuration freed but the allocator kept (the configurations
run in order, in this process and on the same cluster).

Growth exponents (``exponents``), per configuration: the least-squares slopes of
log(``warm_median_s``) and log(``peak_rss_summed_mb``) against log(tasks) at each size (over
``--tasks``) and against log(states) at each number of tasks (over ``--sizes``); None with a
single value.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import os
import re
import time
from typing import Any, Callable

import numpy as np

from ...parallel import limit_blas_threads
from ...tasks.features import factorial_rewards
from ...learners.fitting import make_objective
from ...tasks.task_set import reward_features
from ...objectives.sharding import sharded
from ...planning import clear_caches, planning_budget
from ...datasets.synthetic import random_coefficients
from .scale_jobs import configurations, dask_client

__all__ = ["N_PRIMITIVES", "peak_rss_mb", "reset_peak", "process_memory", "growth_exponent", "evaluate",
           "run_evaluations"]

#: primitives of the random dictionary the rewards are made from
N_PRIMITIVES = 5
#: the coefficients' perturbation of each warm call
PERTURBATION = 1e-3


def peak_rss_mb(pid: int | None = None) -> float | None:
    """Peak resident memory (MiB, ``VmHWM``) of process ``pid`` (None: this one); None if unreadable."""
    try:
        with open(f"/proc/{'self' if pid is None else pid}/status") as fh:
            found = re.search(r"^VmHWM:\s+(\d+)\s+kB", fh.read(), re.MULTILINE)
    except OSError:
        return None
    return int(found.group(1)) / 1024.0 if found else None


def reset_peak(pid: int | None = None) -> bool:
    """Reset the peak resident memory of process ``pid`` (None: this one) to its current one; success."""
    try:
        with open(f"/proc/{'self' if pid is None else pid}/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return False
    return True


def _uss_mb(pid: int | None = None) -> float | None:
    """Private memory (MiB, psutil's USS) of process ``pid`` (None: this one); None without psutil."""
    try:
        import psutil  # type: ignore[import-untyped,unused-ignore]

        return float(psutil.Process(pid).memory_full_info().uss) / 2**20
    except Exception:  # psutil missing, the process gone, or USS unavailable on the platform
        return None


def _shard_pids(objective: Any) -> list[int]:
    """The pids of a sharded objective's shard processes ([] for the objective itself or dask actors)."""
    shards = getattr(objective, "shards", None)
    return [h.proc.pid for h in getattr(shards, "handles", []) if hasattr(h, "proc")]


def process_memory(pids: list[int], client: Any = None) -> dict:
    """``peak_rss_mb`` of this process and of ``pids`` (or of ``client``'s workers), their sum, the others' USS."""
    peaks: dict[str, float | None] = {"driver": peak_rss_mb()}
    uss: list[float | None]
    if client is not None:
        peaks.update({f"worker {i}": v for i, v in enumerate(client.run(peak_rss_mb).values())})
        uss = list(client.run(_uss_mb).values())
    else:
        peaks.update({f"shard {i + 1}": peak_rss_mb(pid) for i, pid in enumerate(pids)})
        uss = [_uss_mb(pid) for pid in pids]
    values = list(peaks.values())
    return {"peak_rss_mb": peaks, "peak_rss_summed_mb": None if None in values else float(sum(values)),  # type: ignore[arg-type]
            "workers_uss_mb": None if None in uss else [float(u) for u in uss]}  # type: ignore[arg-type]


def _reset_peaks(client: Any) -> bool:
    gc.collect()
    ok = reset_peak()
    if client is not None:
        ok = all(client.run(reset_peak).values()) and ok
    return ok


def _summary(loss: np.ndarray, grad: np.ndarray, Phi: Any) -> tuple:
    """Losses (n,) and feature gradients ``Phi^T dJ/dR_i`` (n, p): what is compared across configurations."""
    return np.array(loss, dtype=np.float64), grad.reshape(len(grad), -1) @ Phi


def evaluate(objective: Any, rewards: Callable[[int], np.ndarray], Phi: Any, extra: dict, repeats: int) -> tuple:
    """One configuration's evaluations of ``objective`` (see the module docstring).

    Parameters
    ----------
    objective : Objective
        Its warm starts and its MDP's planning caches are emptied first.
    rewards : callable
        ``rewards(r)`` (n, S, A): ``r = -1`` the cold call's, ``r = 0, 1, ...`` the warm calls'.
    Phi : ndarray, shape (S*A, p)
    extra : dict
        ``n_jobs``, ``backend`` and ``client`` of :func:`~factirl_opt.objectives.sharding.sharded`.
    repeats : int

    Returns
    -------
    entry : dict
        ``cold_s``, ``warm_s``, ``warm_median_s``, memory (:func:`process_memory`), ``peak_reset``.
    summary : tuple
        The cold call's losses (n,) and feature gradients (n, p).
    """
    objective.reset()
    clear_caches(objective.mdp)
    client = extra.get("client")
    peak_reset = _reset_peaks(client)
    with sharded(objective, extra.get("n_jobs"), extra.get("backend", "processes"), client) as obj:
        R = rewards(-1)
        t0 = time.perf_counter()
        loss, grad = obj.loss_and_grad(R)
        cold = time.perf_counter() - t0
        summary = _summary(loss, grad, Phi)
        del loss, grad, R
        warm = []
        for r in range(repeats):
            R = rewards(r)
            t0 = time.perf_counter()
            obj.loss_and_grad(R)
            warm.append(time.perf_counter() - t0)
            del R
        memory = process_memory(_shard_pids(obj), client)
    entry = {"n_jobs": extra.get("n_jobs"), "backend": extra.get("backend", "processes"), "cold_s": cold,
             "warm_s": warm, "warm_median_s": float(np.median(warm)), **memory, "peak_reset": peak_reset}
    return entry, summary


def _max_abs_diff(summary: tuple, ref: tuple) -> float:
    return float(max(np.max(np.abs(a - b)) for a, b in zip(summary, ref)))


def _one_point(size: int, n: int, args: argparse.Namespace, configs: list, fit_problem: Callable) -> dict:
    """Every configuration's evaluations on the problem of side ``size`` with ``n`` tasks."""
    problem = fit_problem(size, argparse.Namespace(**dict(vars(args), tasks=n)))
    mdp = problem["mdp"]
    Phi: Any = reward_features(mdp, problem["features"], min_columns=N_PRIMITIVES)  # (S*A, p)
    objective = make_objective(mdp, problem["demos"], args.beta)
    del problem["demos"]
    rng = np.random.default_rng([args.seed, size, n])
    D = rng.standard_normal((Phi.shape[1], N_PRIMITIVES))
    H = random_coefficients(n, N_PRIMITIVES, rng=rng)
    seed = int(rng.integers(2**31))

    def rewards(r: int) -> np.ndarray:
        noise = 0.0 if r < 0 else PERTURBATION * np.random.default_rng([seed, r]).standard_normal(H.shape)
        return factorial_rewards(mdp, Phi, D, H + noise)

    out: dict[str, Any] = {"n_states": mdp.n_states, "n_actions": mdp.n_actions, "n_tasks": n,
                           "n_features": int(Phi.shape[1]), "build_s": problem["build_s"],
                           "demonstrations_s": problem["demonstrations_s"], "configurations": {}}
    ref = None
    for label, extra in configs:
        entry, summary = evaluate(objective, rewards, Phi, extra, max(1, args.repeats))
        ref = summary if ref is None else ref
        entry["max_abs_diff"] = _max_abs_diff(summary, ref)
        out["configurations"][label] = entry
    clear_caches(mdp)
    return out


def growth_exponent(x: list, y: list) -> float | None:
    """Least-squares slope of log(y) against log(x); None with fewer than two distinct x or a missing y."""
    if len(set(x)) < 2 or any(v is None or v <= 0 for v in y):
        return None
    return float(np.polyfit(np.log(np.asarray(x, dtype=float)), np.log(np.asarray(y, dtype=float)), 1)[0])


def _exponents(points: dict, sizes: list, tasks: list, labels: list) -> dict:
    """Per configuration and measure, the exponents against tasks (per size) and against states (per tasks)."""
    out: dict = {}
    for label in labels:
        out[label] = {}
        for key in ("warm_median_s", "peak_rss_summed_mb"):
            def row(s: int, n: int) -> tuple:
                e = points[f"{s}x{s}"][str(n)]
                return e["n_tasks"], e["n_states"], e["configurations"][label][key]

            out[label][key] = {
                "tasks": {f"{s}x{s}": growth_exponent([row(s, n)[0] for n in tasks], [row(s, n)[2] for n in tasks])
                          for s in sizes},
                "states": {str(n): growth_exponent([row(s, n)[1] for s in sizes], [row(s, n)[2] for s in sizes])
                           for n in tasks},
            }
    return out


def run_evaluations(args: argparse.Namespace, fit_problem: Callable) -> dict:
    """The ``--evaluations`` mode (see the module docstring).

    Parameters
    ----------
    args : argparse.Namespace
        The scale benchmark's validated options; ``args.tasks`` a list.
    fit_problem : callable
        ``fit_problem(size, args) -> dict`` with ``mdp``, ``demos``, ``features``, ``build_s``,
        ``demonstrations_s`` (``args.tasks`` an int).
    """
    configs = configurations(args.jobs, args.dask)
    load_before = os.getloadavg()
    points: dict = {}
    with contextlib.ExitStack() as stack, limit_blas_threads(args.blas_threads), planning_budget(args.max_bytes):
        if args.dask:
            client = stack.enter_context(dask_client())
            configs = [(label, dict(extra, client=client) if label == "dask" else extra) for label, extra in configs]
        for size in args.sizes:
            points[f"{size}x{size}"] = {str(n): _one_point(size, n, args, configs, fit_problem) for n in args.tasks}
    labels = [label for label, _ in configs]
    return {
        "benchmark": "scale", "mode": "evaluations", "sizes": points,
        "exponents": _exponents(points, list(args.sizes), list(args.tasks), labels),
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "settings": {
            "sizes": list(args.sizes), "tasks": list(args.tasks), "n_demos": args.n_demos, "length": args.length,
            "beta": args.beta, "repeats": max(1, args.repeats), "max_bytes": args.max_bytes, "seed": args.seed,
            "blas_threads": args.blas_threads, "configurations": labels, "n_primitives": N_PRIMITIVES,
            "dask_cluster": "LocalCluster(n_workers=2, threads_per_worker=1, processes=True)" if args.dask else None,
            "evaluation": "policy-matching loss_and_grad at Phi D (H + 1e-3 N(0, 1)) per warm call, after a cold call "
                          "at Phi D H; planning caches and warm starts emptied per configuration",
            "memory": "VmHWM (/proc) of the driver and of the shard processes or dask workers, reset per "
                      "configuration, summed; forked shards count pages shared with the driver (workers_uss_mb: "
                      "their private memory at the end)",
        },
    }
