"""How an objective is evaluated: in this process, or sharded by tasks or by whole environments.

:func:`sharded` is the one place that chooses. The learners hold their execution settings as
one value, :class:`Execution` (``n_jobs``, ``backend``, ``client``, the planner and its
``planner_options``), built once from the estimator and passed down whole; its
:meth:`Execution.evaluate` opens the planning budget and the shards around a fit and yields
the objective to use.
"""

from __future__ import annotations

import contextlib
import dataclasses
import warnings
from collections.abc import Iterator
from typing import Any

from ..parallel.shards import Client, check_backend, daemonic, dask_workers, effective_n_jobs, in_worker
from ..planning.budget import options_budget
from .._params import ParameterGroup
from ._base import Objective
from .distributed import ShardedObjective
from .environments import MultiEnvironmentObjective
from .sharded_environments import ShardedEnvironments

__all__ = ["sharded", "Execution"]

#: set once this (daemonic) process has warned that its shards run in it (:func:`sharded`)
_WARNED_DAEMONIC: list[bool] = []


@dataclasses.dataclass(frozen=True, repr=False)
class Execution(ParameterGroup):
    """Where and how a fit runs and is watched: the estimators' ``execution`` parameter.

    None of these settings is part of the model: same seed, same result for every ``n_jobs``
    and backend. An estimator's ``execution=None`` is ``Execution()``; its fields are nested
    parameters (``set_params(execution__n_jobs=4)``).

    Parameters
    ----------
    n_jobs : int or None, default=None
        Task shards evaluated in parallel (:func:`sharded`; None or 1: this process, -1: every
        core); results do not depend on it.
    backend : {"processes", "dask"}, default="processes"
        How the shards run (:mod:`factirl_opt.parallel.shards`).
    client : dask.distributed.Client, optional
        The cluster of ``backend="dask"``.
    planner : str, default="auto"
        Planning engine (``factirl_opt.available_planners()``); the shards use its name.
    planner_options : dict, optional
        ``{"max_bytes": ...}``: the planning budget in force during the fit
        (:func:`~factirl_opt.planning.budget.options_budget`).
    verbose : bool, default=False
        Progress bars on stderr.
    callback : callable, optional
        ``callback(iteration, total_loss)`` after each iteration of a fit (and each step of a transfer).
    """

    n_jobs: int | None = None
    backend: str = "processes"
    client: Client | None = None  # distributed.Client, resolvable without importing distributed
    planner: Any = "auto"
    planner_options: dict | None = None
    verbose: bool = False
    callback: Any = None

    def quiet(self) -> "Execution":
        """These settings without progress bar or callback (the inner fits of a search or a start)."""
        return dataclasses.replace(self, verbose=False, callback=None)

    def budget(self) -> contextlib.AbstractContextManager:
        """The planning budget of ``planner_options`` in force while the block is open."""
        return options_budget(self.planner_options)

    def shards(self, objective: Any) -> contextlib.AbstractContextManager:
        """:func:`sharded` with these settings: the objective to use while the block is open."""
        return sharded(objective, self.n_jobs, self.backend, self.client, self.planner)

    @contextlib.contextmanager
    def evaluate(self, objective: Any) -> Iterator[Any]:
        """The planning budget and the shards of a fit, together: yields the objective to use."""
        with self.budget(), self.shards(objective) as obj:
            yield obj


@contextlib.contextmanager
def sharded(objective: Any, n_jobs: int | None = None, backend: str = "processes", client: Any = None,
            planner: Any = None) -> Iterator[Any]:
    """The objective evaluated over task shards while the block is open, its workers stopped after.

    Parameters
    ----------
    objective : Objective
    n_jobs : int or None
        Shards (:func:`factirl_opt.parallel.shards.effective_n_jobs`: None is 1, -1 every core); with
        ``backend="dask"``, None or -1 is one shard per worker of ``client``.
    backend : {"processes", "dask"}
    client : dask.distributed.Client, optional
    planner : str, optional
        The planner name the shards use (default the objective's).

    Yields
    ------
    Objective or ShardedObjective
        ``objective`` itself when one shard is asked for (``n_jobs=1``: today's code path),
        inside a worker process, for a single task or a single environment; else a
        :class:`ShardedObjective` (tasks of one MDP) or a
        :class:`~factirl_opt.objectives.sharded_environments.ShardedEnvironments` (whole
        environments per shard), closed when the block exits (also on an error or a
        KeyboardInterrupt).
    """
    check_backend(backend, client)
    workers = dask_workers(client) if backend == "dask" and not in_worker() else None
    if workers is not None and not workers:
        warnings.warn(f"the Dask cluster of {client!r} has no worker: this fit runs unsharded in this process (fits do "
                      "not wait for workers to join; call client.wait_for_workers(n) before the fit)", RuntimeWarning,
                      stacklevel=3)
        n = 1
    elif workers is not None and n_jobs in (None, -1):
        n = len(workers)
    else:
        n = effective_n_jobs(n_jobs)
        if n > 1 and backend == "processes" and daemonic():
            if not _WARNED_DAEMONIC:  # once per process: a fit can open shards several times (start, fit, search)
                _WARNED_DAEMONIC.append(True)
                warnings.warn(f"this fit runs in a daemonic process (a multiprocessing.Pool worker, or a Process with "
                              f"daemon=True), which cannot start the processes of its n_jobs={n_jobs} shards: they run "
                              "in this process, one after another (same result; run the work in non-daemonic processes, "
                              "e.g. concurrent.futures.ProcessPoolExecutor, to shard)", RuntimeWarning, stacklevel=3)
            n = 1
    sharded_obj: Any
    if n > 1 and isinstance(objective, MultiEnvironmentObjective) and len(objective.group_mdps) > 1:
        sharded_obj = ShardedEnvironments(objective, n, backend, client, planner if isinstance(planner, str) else "auto")
    elif n > 1 and isinstance(objective, Objective) and objective.n_tasks > 1:
        sharded_obj = ShardedObjective(objective, n, backend, client, planner if isinstance(planner, str) else None)
    else:
        yield objective
        return
    try:
        yield sharded_obj
    finally:
        sharded_obj.close()
