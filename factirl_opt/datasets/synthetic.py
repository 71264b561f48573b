"""Synthetic multi-task problems: random dictionaries, mixing coefficients, rewards, demonstrations.

The one recipe used by the experiments, the benchmarks, the notebooks and the tests:
dictionary ``D`` -> coefficients ``H`` -> rewards ``R_i = D h_i`` -> expert demonstrations
(:func:`synthetic_tasks`).

Distributions (the paper leaves them open; fixed here, docs/maths.md §9):

- dictionary: ``D[j, l] ~ N(0, 1)`` i.i.d. over parameters j and primitives l;
- ``"gaussian"`` coefficients: ``H[i, l] ~ N(0, 1)``;
- ``"nonneg"`` coefficients: ``H[i, l] = |N(0, 1)|`` (half-normal), for the nonnegative
  H-step variants;
- ``sparsity`` (both kinds): each coefficient is zeroed with that probability, keeping at
  least one nonzero coefficient per task.
"""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import RNGLike, as_rng, check_array, check_int, check_mdp, check_real
from ..tasks.demonstrations import sample_demonstrations
from ..tasks.features import task_rewards
from ..exceptions import ValidationError

from ..mdp.tabular import TabularMDP  # at run time too: typing.get_type_hints resolves the annotations

__all__ = ["random_dictionary", "random_coefficients", "SyntheticTasks", "synthetic_tasks"]

COEFFICIENT_KINDS = ("gaussian", "nonneg")


def random_dictionary(n_params: int, n_primitives: int = 5, rng: RNGLike = None) -> NDArray[np.float64]:
    """A random dictionary ``D`` of shape (n_params, n_primitives), entries N(0, 1)."""
    n_params = check_int(n_params, "n_params", minimum=1)
    n_primitives = check_int(n_primitives, "n_primitives", minimum=1)
    return as_rng(rng).standard_normal((n_params, n_primitives))


def random_coefficients(n_tasks: int, n_primitives: int = 5, kind: str = "gaussian", sparsity: float = 0.0,
                        rng: RNGLike = None) -> NDArray[np.float64]:
    """Random mixing coefficients ``H`` of shape (n_tasks, n_primitives).

    Parameters
    ----------
    kind : {"gaussian", "nonneg"}
        N(0, 1) or half-normal ``|N(0, 1)|`` entries.
    sparsity : float in [0, 1)
        Probability that a coefficient is zero (at least one stays nonzero per task).
    """
    n_tasks = check_int(n_tasks, "n_tasks", minimum=1)
    n_primitives = check_int(n_primitives, "n_primitives", minimum=1)
    if kind not in COEFFICIENT_KINDS:
        raise ValidationError(f"kind must be one of {COEFFICIENT_KINDS}; got {kind!r}")
    sparsity = check_real(sparsity, "sparsity", 0.0, 1.0, high_open=True, what="a probability")
    rng = as_rng(rng)
    H = rng.standard_normal((n_tasks, n_primitives))
    if kind == "nonneg":
        H = np.abs(H)
    if sparsity > 0:
        zero = rng.random((n_tasks, n_primitives)) < sparsity
        keep = rng.integers(0, n_primitives, size=n_tasks)
        zero[np.arange(n_tasks), keep] = False
        H[zero] = 0.0
    return H


@dataclasses.dataclass
class SyntheticTasks:
    """A synthetic multi-task problem (see :func:`synthetic_tasks`).

    Attributes
    ----------
    dictionary : ndarray, shape (S*A, k)
    coefficients : ndarray, shape (n, k)
    rewards : ndarray, shape (n, S, A)
    demos : list of n int arrays, each (m, L, 2)
    """

    dictionary: np.ndarray
    coefficients: np.ndarray
    rewards: np.ndarray
    demos: list


def synthetic_tasks(mdp: TabularMDP, n_tasks: int, n_demos: int, length: int, n_primitives: int = 5,
                    dictionary: ArrayLike | None = None, kind: str = "gaussian", sparsity: float = 0.0,
                    rng: RNGLike = None, demo_rng: RNGLike = None,
                    planner: str = "auto") -> SyntheticTasks:
    """Draw tasks from a (random or given) dictionary and sample an expert's demonstrations.

    Draws, in this order: the dictionary from ``rng`` (unless given), the coefficients from
    ``rng``, then the demonstrations from ``demo_rng`` (default: ``rng``, after the draws
    above). Giving separate streams keeps the tasks fixed when only the demonstrations vary.

    Parameters
    ----------
    mdp : TabularMDP
    n_tasks : int
    n_demos : int
        Demonstrations per task.
    length : int
        Steps per demonstration.
    n_primitives : int, default=5
        k (ignored when ``dictionary`` is given).
    dictionary : array_like, shape (S*A, k), optional
        A fixed dictionary (e.g. to draw test tasks from the training tasks' dictionary).
    kind, sparsity
        See :func:`random_coefficients`.
    rng, demo_rng : numpy.random.Generator or int or None
    planner : str, default="auto"
        Planner of the expert's ``Q*`` (:func:`factirl_opt.available_planners`).

    Returns
    -------
    SyntheticTasks
    """
    check_mdp(mdp)
    rng = as_rng(rng)
    demo_rng = rng if demo_rng is None else as_rng(demo_rng)
    S, A = mdp.n_states, mdp.n_actions
    D = random_dictionary(S * A, n_primitives, rng) if dictionary is None else check_array(dictionary, "dictionary", ndim=2)
    H = random_coefficients(n_tasks, D.shape[1], kind=kind, sparsity=sparsity, rng=rng)
    R = task_rewards(D, H, S, A)
    demos = sample_demonstrations(mdp, R, n_demos, length, rng=demo_rng, planner=planner)
    return SyntheticTasks(dictionary=D, coefficients=H, rewards=R, demos=typing.cast(list, demos))
