"""Imported by the fork server of shard processes (:func:`factirl_opt.parallel.shards._context`).

Importing it imports the library (its parent packages), once, in the server; and it marks the
server, so every process it forks, as a worker (:func:`~factirl_opt.parallel.shards.mark_worker`):
a fit inside runs with one job, also one in a caller's ``__main__`` imported there.
"""

from .shards import mark_worker

mark_worker()

from .._threads import _blas_libraries  # noqa: E402

_blas_libraries()  # the BLAS libraries found once (threadpoolctl), not in every shard process
