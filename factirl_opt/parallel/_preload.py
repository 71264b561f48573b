"""Imported by the fork server of shard processes (:func:`factirl_opt.parallel.shards._context`).

Importing it imports the library (its parent packages), once, in the server; it marks the
server, so every process it forks, as a worker (:func:`~factirl_opt.parallel.shards.mark_worker`:
a fit inside runs with one job); and it finds the BLAS libraries once, not in every shard process.
"""

from .._threads import _blas_libraries
from .shards import mark_worker

mark_worker()
_blas_libraries()
