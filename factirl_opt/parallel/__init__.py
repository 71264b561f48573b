"""The parallel layer: tasks split into shards served by worker processes or a Dask cluster.

The objectives' distributed wrappers (:mod:`factirl_opt.objectives.distributed`) use it; the
learners only pass the execution settings (``n_jobs``, ``backend``, ``client``) through.
A *backend* is always one of :data:`BACKENDS`: how shards are served.

Threads: the library's batched small solves run with BLAS limited to ``FACTIRL_BLAS_THREADS``
threads (default 1); :func:`limit_blas_threads` sets another limit around a block of code (the
experiment runner and the benchmarks open one around whole runs).
"""

from .._threads import limit_blas_threads
from .shards import BACKENDS, Shards, check_backend, contiguous_shards, effective_n_jobs, in_worker, start_shard_server

__all__ = ["BACKENDS", "Shards", "check_backend", "contiguous_shards", "effective_n_jobs", "in_worker", "limit_blas_threads", "start_shard_server"]
