"""The parallel layer: tasks split into shards served by worker processes or a Dask cluster.

The objectives' distributed wrappers (:mod:`factirl_opt.objectives.distributed`) use it; the
learners only pass the execution settings (``n_jobs``, ``backend``, ``client``) through.
A *backend* is always one of :data:`BACKENDS`: how shards are served.
"""

from .shards import BACKENDS, Shards, check_backend, contiguous_shards, effective_n_jobs, in_worker

__all__ = ["BACKENDS", "Shards", "check_backend", "contiguous_shards", "effective_n_jobs", "in_worker"]
