"""A memory budget for planning: tasks planned, solved and released chunk by chunk (docs/maths.md §4).

Without a budget an objective plans all the tasks it is asked about at once and keeps each
task's factorisation while it differentiates (the adjoint, the Jacobian products), and the
sparse planner caches up to ``CACHE_GROUPS_PER_TASK`` factorisations per task between
evaluations (:mod:`~factirl_opt.planning.cache`): planning memory grows like tasks x (the fill
of one factorisation, about ``S log S`` on grids, plus a few (S, A) arrays per task).

With a budget of ``max_bytes``, an objective whose tasks' estimated planning memory
(:func:`task_bytes`) exceeds it splits them into chunks that fit (:func:`chunk_size`, at least
one task). Each chunk is planned with a transient factorisation cache
(:meth:`~factirl_opt.planning.Planner.transient_cache`), solved and differentiated, and its
factorisations are released before the next chunk starts. A Gauss-Newton linearisation keeps
only each task's greedy policy and, for every Jacobian product, plans its chunk again from it
(one factorisation per task), applies the product and releases it. Every task's arithmetic is
that of an evaluation without a budget, except that factorisations are built afresh instead
of found in the cache or updated by a low-rank correction: results agree to floating-point
accuracy (about 1e-15 relative per evaluation), at the cost of more factorisations. Under a
budget that all the tasks fit in, nothing changes.

Where the budget comes from: an objective's own ``planner_options={"max_bytes": ...}``, else
the :func:`planning_budget` context in force where the objective's method is called (a
:mod:`contextvars` variable: each thread, and each asyncio task, has its own), else none. The
budget bounds planning memory only; the arrays the caller passes in and gets back (rewards,
gradients, a Jacobian of (n, S*A, p)) and the objective's statistics grow with the tasks.
"""

from __future__ import annotations

import contextlib
import contextvars
import math
import numbers
from collections.abc import Iterator, Mapping
from typing import Any

from ..exceptions import ValidationError

__all__ = ["budget_options", "options_budget", "check_max_bytes", "check_planner_options", "planning_budget", "get_planning_budget",
           "effective_budget", "chunk_size", "task_bytes", "WORK_ARRAYS_PER_TASK", "ARRAYS_PER_DIRECTION", "PLANNER_OPTIONS"]

#: (S, A) float arrays an objective's evaluation holds per task besides its factorisations (Q,
#: the Boltzmann policy, residuals, dJ/dQ, dJ/dR and temporaries) ...
WORK_ARRAYS_PER_TASK = 12
#: ... and (S, A) float arrays per direction of a Jacobian (tangents, their softmax products)
ARRAYS_PER_DIRECTION = 6

#: the keys ``planner_options`` accepts
PLANNER_OPTIONS = ("max_bytes",)

_BUDGET: contextvars.ContextVar[int | None] = contextvars.ContextVar("factirl_opt_planning_budget", default=None)


def check_max_bytes(max_bytes: Any, name: str = "max_bytes") -> int | None:
    """``max_bytes`` as an int, or None (no budget).

    Raises
    ------
    ValidationError
        For anything but None or a whole number of bytes >= 1 (``16e9`` is accepted), naming
        the value.
    """
    if max_bytes is None:
        return None
    ok = isinstance(max_bytes, numbers.Real) and not isinstance(max_bytes, bool)
    if ok:
        value = float(max_bytes)
        ok = math.isfinite(value) and value >= 1 and value.is_integer()
    if not ok:
        raise ValidationError(f"{name} (the planning memory budget) must be None or a whole number of bytes >= 1; "
                              f"got {max_bytes!r}")
    return int(max_bytes)


def check_planner_options(options: Any) -> dict[str, Any]:
    """Validated ``planner_options``: a mapping with the keys of :data:`PLANNER_OPTIONS` only.

    Returns a new dict with every key (``max_bytes`` None when not given).
    """
    if options is None:
        options = {}
    if not isinstance(options, Mapping):
        raise ValidationError(f"planner_options must be a dict or None; got {type(options).__name__} {options!r}")
    unknown = sorted(str(k) for k in options if k not in PLANNER_OPTIONS)
    if unknown:
        raise ValidationError(f"unknown planner_options {', '.join(map(repr, unknown))}; known: {', '.join(PLANNER_OPTIONS)}")
    return {"max_bytes": check_max_bytes(options.get("max_bytes"), "planner_options['max_bytes']")}


@contextlib.contextmanager
def planning_budget(max_bytes: int | float | None) -> Iterator[int | None]:
    """Context manager: objectives evaluated inside the block (in this thread or asyncio task)
    plan within ``max_bytes`` bytes, unless they have a budget of their own; None lifts it.

    Yields the validated budget. Example: ``with planning_budget(16e9): model.fit(mdp, demos)``.
    """
    token = _BUDGET.set(check_max_bytes(max_bytes))
    try:
        yield _BUDGET.get()
    finally:
        _BUDGET.reset(token)


def get_planning_budget() -> int | None:
    """The budget of the innermost :func:`planning_budget` block in force here, or None."""
    return _BUDGET.get()


def effective_budget(own: int | None) -> int | None:
    """An objective's own budget when it has one, else the context's (:func:`get_planning_budget`)."""
    return own if own is not None else _BUDGET.get()


def task_bytes(planner: Any, directions: int = 0) -> int:
    """Estimated planning memory of one task during an evaluation (bytes): the planner's
    (:meth:`~factirl_opt.planning.Planner.task_bytes`) plus :data:`WORK_ARRAYS_PER_TASK` (S, A)
    float arrays, and :data:`ARRAYS_PER_DIRECTION` more per direction of a Jacobian
    (``directions``: its columns; 0 for a gradient)."""
    arrays = WORK_ARRAYS_PER_TASK + ARRAYS_PER_DIRECTION * max(0, int(directions))
    return int(planner.task_bytes()) + 8 * planner.S * planner.A * arrays


def chunk_size(n_tasks: int, per_task: int, budget: int | None) -> int:
    """Tasks per chunk so that a chunk of ``per_task`` bytes each fits in ``budget`` (>= 1).

    ``n_tasks`` (one chunk) without a budget or when every task fits.
    """
    if budget is None or n_tasks * per_task <= budget:
        return max(1, n_tasks)
    return max(1, min(n_tasks, budget // max(1, per_task)))


def budget_options(objective: Any) -> dict | None:
    """The ``planner_options`` that carry ``objective``'s budget into another process.

    Its own ``max_bytes`` if it has one, else the budget of the calling context
    (:func:`planning_budget`), read when the shards are built: a shard in a worker process or on a
    Dask worker then plans under the budget the fit was started with. None without a budget.
    """
    budget = effective_budget(getattr(objective, "max_bytes", None))
    return None if budget is None else {"max_bytes": budget}


def options_budget(planner_options: Any) -> contextlib.AbstractContextManager:
    """The budget of an estimator's ``planner_options`` as a context for its fit.

    :func:`planning_budget` with ``planner_options["max_bytes"]`` when one is given; otherwise
    a context that changes nothing (a budget set around the fit by the caller stays in force).

    Raises
    ------
    ValidationError
        As :func:`check_planner_options`.
    """
    max_bytes = check_planner_options(planner_options)["max_bytes"]
    return contextlib.nullcontext() if max_bytes is None else planning_budget(max_bytes)
