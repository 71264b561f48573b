"""How an objective is evaluated: in this process, or sharded by tasks or by whole environments.

:func:`sharded` is the one place that chooses: the learners call it with the execution
settings (``n_jobs``, ``backend``, ``client``) and use what it yields as their objective.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from typing import Any

from ..parallel.shards import check_backend, dask_workers, effective_n_jobs, in_worker
from ._base import Objective
from .distributed import ShardedObjective
from .environments import MultiEnvironmentObjective
from .sharded_environments import ShardedEnvironments

__all__ = ["sharded"]


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
