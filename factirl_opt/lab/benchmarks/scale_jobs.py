"""The scale benchmark's fits side by side: one FactIRL fit, its tasks' evaluations over shards.

``bench scale --fit-iter N --jobs J [J ...] [--dask]``: per size, the world, demonstrations and
features of the ``--fit-iter`` mode (:func:`factirl_opt.lab.benchmarks.scale.fit_problem`, so the
problem is the one of ``results/scale``), then the same fit for every configuration, in this
one process:

- ``n_jobs=J`` for each J of ``--jobs`` (``FactIRL(n_jobs=J)``, backend ``"processes"``; the
  first is the reference; ``--dask`` alone compares with ``n_jobs=1``);
- ``dask`` with ``--dask``: ``FactIRL(backend="dask", client=client)`` on a
  ``distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True)`` started once.

First a tiny fit per configuration (3 tasks, one outer iteration: imports cvxpy here and in the
cluster's workers), then ``--repeats`` rounds, each running every configuration once in turn
(so that load changes on a shared machine hit them alike). Reported per configuration:
``wall_s`` (every fit), ``median_s``, ``speed_up`` (the reference's median over this one's),
``cpu_driver_s`` and ``cpu_children_s`` (user + system CPU of this process and of its child
processes during each fit: finished children's ``RUSAGE_CHILDREN`` plus, with psutil, the
growth of the live ones', e.g. the cluster's workers, whose idle background work then counts in
every configuration's figure), ``n_evaluations``, ``n_iter`` and
``final_loss`` (the last entry of ``loss_history_``) of the fit, and, when the objective was
sharded, ``bytes_sent`` (array bytes sent to and received from the shards by the calls),
``bytes_setup`` (the shards' specs sent at their start),
``bytes_per_evaluation`` and ``n_restarts`` of the last fit (:class:`factirl_opt.parallel.shards.Shards`;
with ``n_jobs``, the first shard runs in this process and sends nothing);
``max_abs_diff``: the largest absolute difference of the last fit's ``dictionary_`` and
``coefficients_`` from the reference's.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import time
from typing import Any, Callable, Iterator

import numpy as np

from ...parallel import limit_blas_threads, start_shard_server
from ...exceptions import MissingDependencyError, ValidationError
from ...objectives import distributed
from ...planning import planning_budget

__all__ = ["check_jobs", "configurations", "dask_client", "record_traffic", "cpu_seconds", "run_side_by_side"]

#: tasks and outer iterations of the warm-up fit
WARM_UP_TASKS = 3


def check_jobs(jobs: list) -> None:
    """Refuse ``--jobs`` values other than positive integers and -1 (ValidationError naming the value)."""
    for j in jobs:
        if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or not (j > 0 or j == -1):
            raise ValidationError(f"--jobs values must be positive integers or -1 (every core); got {j!r}")


def configurations(jobs: list | None, dask: bool) -> list[tuple[str, dict]]:
    """``(label, FactIRL keyword arguments)`` per configuration, the reference first; the dask one's
    ``client`` is filled in later."""
    out: list[tuple[str, dict]] = [(f"n_jobs={j}", {"n_jobs": int(j)}) for j in (jobs or [1])]
    if dask:
        out.append(("dask", {"backend": "dask"}))
    return out


@contextlib.contextmanager
def dask_client() -> Iterator[Any]:
    """A client of a 2-worker local cluster (one thread each, worker processes), closed after."""
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:
        raise MissingDependencyError('--dask needs the dask extra: pip install -e ".[dask]"') from exc
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            yield client


@contextlib.contextmanager
def record_traffic() -> Iterator[list]:
    """While open, every :class:`~factirl_opt.objectives.distributed.ShardedObjective` closed appends its
    traffic to the list yielded: ``bytes_sent``, ``bytes_setup``, ``n_restarts`` (its shards') and
    ``n_evaluations`` (its own). The class's ``close`` is wrapped for the block only."""
    records: list = []
    cls = distributed.ShardedObjective
    original = cls.close

    def close(self: Any) -> None:
        shards = self.shards
        records.append({"bytes_sent": int(shards.bytes_sent), "bytes_setup": int(shards.bytes_setup),
                        "n_restarts": int(shards.n_restarts), "n_evaluations": int(self.n_evaluations)})
        original(self)

    cls.close = close  # type: ignore[method-assign]
    try:
        yield records
    finally:
        cls.close = original  # type: ignore[method-assign]


def _live_children() -> dict[int, float]:
    """CPU seconds (user + system) of this process's live descendants, by pid ({} without psutil)."""
    try:
        import psutil  # type: ignore[import-untyped,unused-ignore]
    except ImportError:
        return {}
    out = {}
    for child in psutil.Process().children(recursive=True):
        try:
            t = child.cpu_times()
            out[child.pid] = t.user + t.system
        except psutil.Error:
            pass
    return out


def cpu_seconds() -> tuple[float, float, dict[int, float]]:
    """This process's CPU seconds, its finished children's, and its live descendants' by pid."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    done = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, done.ru_utime + done.ru_stime, _live_children()


def _timed_fit(model: Any, problem: dict, records: list) -> dict:
    """Fit ``model`` on ``problem``; its wall time, CPU of driver and children, and sharded traffic."""
    n_before = len(records)
    own0, done0, live0 = cpu_seconds()
    t0 = time.perf_counter()
    model.fit(problem["mdp"], problem["demos"])
    wall = time.perf_counter() - t0
    own1, done1, live1 = cpu_seconds()
    live = sum(t - live0.get(pid, 0.0) for pid, t in live1.items())
    return {"wall_s": wall, "cpu_driver_s": own1 - own0, "cpu_children_s": done1 - done0 + live,
            "traffic": records[-1] if len(records) > n_before else None}


def _warm_up(configs: list, problem: dict, make_model: Callable) -> None:
    """A tiny fit per configuration: cvxpy and the library imported here and in the cluster's workers."""
    demos = problem["demos"][:WARM_UP_TASKS]
    for _, extra in configs:
        make_model(problem["features"], **extra, max_iter=1).fit(problem["mdp"], demos)


def _max_abs_diff(model: Any, ref: Any) -> float:
    return float(max(np.max(np.abs(model.dictionary_ - ref.dictionary_)),
                     np.max(np.abs(model.coefficients_ - ref.coefficients_))))


def _entry(extra: dict, runs: list, model: Any, ref_model: Any, ref_median: float | None) -> dict:
    """One configuration's report (see the module docstring)."""
    median = float(np.median([r["wall_s"] for r in runs]))
    traffic = runs[-1]["traffic"]
    entry = {
        "n_jobs": extra.get("n_jobs"), "backend": extra.get("backend", "processes"),
        "wall_s": [r["wall_s"] for r in runs], "median_s": median,
        "speed_up": (ref_median if ref_median is not None else median) / median,
        "cpu_driver_s": [r["cpu_driver_s"] for r in runs], "cpu_children_s": [r["cpu_children_s"] for r in runs],
        "n_evaluations": int(model.n_evaluations_), "n_iter": int(model.n_iter_),
        "final_loss": float(model.loss_history_[-1]),
        "sharded": traffic is not None, "bytes_sent": None, "bytes_setup": None, "bytes_per_evaluation": None,
        "n_restarts": None, "max_abs_diff": _max_abs_diff(model, ref_model),
    }
    if traffic is not None:
        entry.update({k: traffic[k] for k in ("bytes_sent", "bytes_setup", "n_restarts")})
        entry["bytes_per_evaluation"] = traffic["bytes_sent"] / max(1, traffic["n_evaluations"])
    return entry


def _one_size(problem: dict, configs: list, repeats: int, make_model: Callable) -> dict:
    """Every configuration's fits on one problem, ``repeats`` rounds alternating configurations."""
    _warm_up(configs, problem, make_model)
    runs: dict[str, list] = {label: [] for label, _ in configs}
    models: dict[str, Any] = {}
    with record_traffic() as records:
        for _ in range(repeats):
            for label, extra in configs:
                models[label] = make_model(problem["features"], **extra)
                runs[label].append(_timed_fit(models[label], problem, records))
    ref_label = configs[0][0]
    out: dict[str, Any] = {"reference": ref_label, "configurations": {}}
    for label, extra in configs:
        ref_median = None if label == ref_label else out["configurations"][ref_label]["median_s"]
        out["configurations"][label] = _entry(extra, runs[label], models[label], models[ref_label], ref_median)
    return out


def run_side_by_side(args: argparse.Namespace, fit_problem: Callable, fit_model: Callable) -> dict:
    """The ``--fit-iter N --jobs ... [--dask]`` mode (see the module docstring).

    Parameters
    ----------
    args : argparse.Namespace
        The scale benchmark's validated options.
    fit_problem : callable
        ``fit_problem(size, args) -> dict`` with ``mdp``, ``demos``, ``features``, ``build_s``,
        ``demonstrations_s``.
    fit_model : callable
        ``fit_model(args, features, **extra) -> FactIRL``.
    """
    configs = configurations(args.jobs, args.dask)
    if any(extra.get("n_jobs", 1) != 1 for _, extra in configs):
        start_shard_server()  # this process will shard: the server imports the library while the problem is built
    repeats = max(1, args.repeats)
    load_before = os.getloadavg()
    per_size = {}
    with contextlib.ExitStack() as stack, limit_blas_threads(args.blas_threads), planning_budget(args.max_bytes):
        if args.dask:
            client = stack.enter_context(dask_client())
            configs = [(label, dict(extra, client=client) if label == "dask" else extra) for label, extra in configs]
        for size in args.sizes:
            problem = fit_problem(size, args)
            entry = {"n_states": problem["mdp"].n_states, "n_actions": problem["mdp"].n_actions,
                     "n_features": int(problem["features"].shape[1]), "build_s": problem["build_s"],
                     "demonstrations_s": problem["demonstrations_s"]}
            entry.update(_one_size(problem, configs, repeats, lambda features, **extra: fit_model(args, features, **extra)))
            per_size[f"{size}x{size}"] = entry
    return {
        "benchmark": "scale", "mode": "fit-jobs", "sizes": per_size,
        "load_average": {"before": list(load_before), "after": list(os.getloadavg())},
        "settings": {
            "sizes": list(args.sizes), "tasks": args.tasks, "n_demos": args.n_demos, "length": args.length,
            "beta": args.beta, "fit_iter": args.fit_iter, "max_bytes": args.max_bytes, "seed": args.seed,
            "blas_threads": args.blas_threads, "repeats": repeats, "configurations": [label for label, _ in configs],
            "dask_cluster": "LocalCluster(n_workers=2, threads_per_worker=1, processes=True)" if args.dask else None,
            "process": "every configuration in this process, rounds alternating configurations; medians of wall times",
        },
    }
