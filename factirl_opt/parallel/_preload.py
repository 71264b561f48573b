"""Imported by the fork server of shard processes (:func:`factirl_opt.parallel.shards._context`).

Importing it imports the library (its parent packages), once, in the server; it marks the
server, so every process it forks, as a worker (:func:`~factirl_opt.parallel.shards.mark_worker`:
a fit inside runs with one job); it finds the BLAS libraries once; and a shard process
(:data:`~factirl_opt.parallel.shards.SHARD_PROCESS_NAME`, exactly) whose spec does not refer to the
caller's ``__main__`` does not import it: a script without the ``if __name__ == "__main__":``
guard is not run again in each shard process, as ``spawn`` would. Other processes of the server
(a caller's own, started with the ``forkserver`` method) are prepared as usual.
"""

from multiprocessing import spawn as _spawn
from typing import Any

from .._threads import _blas_libraries
from .shards import SHARD_PROCESS_NAME, mark_worker

mark_worker()
_blas_libraries()  # the BLAS libraries found once (threadpoolctl), not in every shard process

_MAIN_KEYS = ("init_main_from_path", "init_main_from_name")
_prepare = _spawn.prepare


def _prepare_shard(data: dict[str, Any]) -> None:
    if data.get("name") == SHARD_PROCESS_NAME:
        data = {key: value for key, value in data.items() if key not in _MAIN_KEYS}
    _prepare(data)


_spawn.prepare = _prepare_shard
