"""Step problems evaluated on the shards of a :class:`~factirl_opt.objectives.distributed.ShardedObjective`.

:func:`factirl_opt.objectives.problems.weights_problem` and :func:`~factirl_opt.objectives.problems.dictionary_problem`
hand a sharded objective's problems to :func:`sharded_weights_problem` and
:func:`sharded_dictionary_problem`. Each shard builds the same problem over its own tasks
(its objective, the features, its rows of ``H``) once per step run, and every evaluation
sends only the parameters:

- weights problem, rows are tasks: ``w_i`` (r, p) in; loss (r,) and ``F^T y_i`` (r, p) out;
  Gauss-Newton Jacobians in reduced form (:func:`.distributed.reduced_least_squares`,
  (r, p+1, p));
- dictionary problem, one row ``vec(D)``: ``vec(D)`` (1, p k) in to every shard; each returns
  its tasks' loss sum and ``Phi^T sum_i y_i h_i^T`` over its tasks (eq. 11), summed here
  (docs/maths.md §8).

The features travel once per problem (``F = Phi D``, (S*A, k), per H-step) and once per fit
(``Phi``); Jacobian-vector products of the matrix-free Gauss-Newton solver move residual
directions (r, S*A). Sums over shards round differently from the sum over all tasks at once
(agreement to rounding).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from solvers import Linearization, StepProblem

__all__ = ["sharded_weights_problem", "sharded_dictionary_problem"]


def _weights_build(objective: Any, features: Any, names: tuple[str, str] | None) -> StepProblem:
    """On a shard: :func:`factirl_opt.objectives.problems.weights_problem` over its tasks."""
    from .problems import weights_problem

    return weights_problem(objective, features, names)


def _dictionary_build(objective: Any, base_features: Any, coefficients: NDArray[np.float64], unit_norm: bool) -> StepProblem:
    """On a shard: :func:`factirl_opt.objectives.problems.dictionary_problem` over its tasks (its rows of H)."""
    from .problems import dictionary_problem

    return dictionary_problem(objective, coefficients, base_features, unit_norm)


def sharded_weights_problem(sobj: Any, features: Any, names: tuple[str, str] | None) -> StepProblem:
    """:func:`factirl_opt.objectives.problems.weights_problem` on the shards of ``sobj`` (rows: tasks; x (r, p));
    ``features`` a :class:`~factirl_opt.tasks.basis.RewardBasis`."""
    p = features.n_params
    token = sobj.make_problem(_weights_build, features, lambda k: (names,))

    def evaluate(method, x, rows, count):
        split, out = sobj.map_tasks("problem_call", np.asarray(x, dtype=np.float64), rows, token, method)
        return tuple(sobj.gather(split, [o[j] for o in out], len(rows)) for j in range(count))

    def linearize(x, rows):
        x = np.asarray(x, dtype=np.float64)
        lt = sobj.keep_linearization(lambda k: sobj.task_call(k, "problem_call", x, rows, token, "linearize", lt))
        split, out = sobj.map_tasks("problem_call", x, rows, token, "linearize", lt)
        loss, residual = (sobj.gather(split, [o[j] for o in out], len(rows)) for j in range(2))
        return Linearization(loss, residual, lambda V: sobj.product(lt, split, "jvp", V),
                             lambda U: sobj.product(lt, split, "vjp", U))

    ls = sobj.least_squares
    return StepProblem(
        loss_and_grad=lambda x, rows: evaluate("loss_and_grad", x, rows, 2),
        residual_jacobian=(lambda x, rows: evaluate("residual_jacobian", x, rows, 3)) if ls else None,
        linearize=linearize if ls else None,
        n_evaluations=lambda: sobj.n_evaluations,
        n_rows=sobj.n_tasks,
        n_params=p,
    )


def sharded_dictionary_problem(sobj: Any, coefficients: NDArray[np.float64], base_features: Any,
                               unit_norm: bool) -> StepProblem:
    """:func:`factirl_opt.objectives.problems.dictionary_problem` on the shards of ``sobj`` (one row, ``vec(D)``)."""
    H = np.asarray(coefficients, dtype=np.float64)
    p = base_features.n_params
    token = sobj.make_problem(_dictionary_build, base_features, lambda k: (H[sobj.parts[k]], unit_norm))
    shards = range(sobj.n_shards)

    def evaluate(method, x, rows, *extra):
        x = np.asarray(x, dtype=np.float64)
        return sobj.call("problem_call", [(k, (x, rows, token, method, *extra)) for k in shards])

    def loss_and_grad(x, rows):
        out = evaluate("loss_and_grad", x, rows)
        return np.sum([o[0] for o in out], axis=0), np.sum([o[1] for o in out], axis=0)

    def linearize(x, rows):
        lt = sobj.keep_linearization(lambda k: ("problem_call", (np.asarray(x, dtype=np.float64), rows, token,
                                                                 "linearize", lt)))
        out = evaluate("linearize", x, rows, lt)
        edges = np.cumsum([0] + [o[1].shape[1] for o in out])  # each shard's residuals, tasks in order

        def jvp(V):
            parts = sobj.shards.call([(k, "product", (lt, "jvp", V)) for k in shards], on_restart=sobj.rebuilt)
            return np.concatenate(parts, axis=1)

        def vjp(U):
            U = np.asarray(U, dtype=np.float64)
            parts = sobj.shards.call([(k, "product", (lt, "vjp", U[:, edges[k]:edges[k + 1]])) for k in shards],
                                     on_restart=sobj.rebuilt)
            return np.sum(parts, axis=0)

        return Linearization(np.sum([o[0] for o in out], axis=0), np.concatenate([o[1] for o in out], axis=1), jvp, vjp)

    return StepProblem(
        loss_and_grad=loss_and_grad,
        linearize=linearize if sobj.least_squares else None,
        n_evaluations=lambda: sobj.n_evaluations,
        n_rows=1,
        n_params=p * H.shape[1],
    )
