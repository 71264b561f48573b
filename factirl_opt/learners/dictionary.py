"""The dictionary of the factorial model: its PCA start, the start's scale, and its normalisation.

Helpers of the factorial learner (docs/maths.md §8) that act on a dictionary ``D`` (p, k) and
coefficients ``H`` (n, k), tasks on the leading axis, with rewards ``R_i = Phi D h_i``:

- :func:`pca_dictionary`: the uncentred PCA of learnt task parameters (the paper's start);
- :func:`metric_pca_dictionary`: the same for feature weights of tasks in several
  environments, in the metric of the mean Gram matrix of their features;
- :func:`shrink_coefficients`: halve a start's coefficients while the total loss decreases;
- :func:`orient_nonneg`: sign-flip primitives before a nonnegative H-step;
- :func:`normalise_dictionary`: unit-norm primitives, H rescaled to match;
- :func:`check_dictionary_norms`: refuse a dictionary whose primitives' norms overflow;
- :func:`constrained_dictionary_solver` and :func:`constrained_start`: the D-step and the
  start of a constrained dictionary (unit-norm columns, nonnegative and/or L1-penalised,
  docs/maths.md §8b).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

import solvers

from .._params import ParameterGroup
from .._validation import as_rng, check_array, check_int, check_real
from ..exceptions import FitInterrupted, ValidationError, translate_solver_errors
from ..interruption import INTERRUPTIONS
from ..tasks.basis import TaskBasis, least_squares_weights
from ..tasks.features import TaskFeatures

__all__ = ["DictionaryConstraint", "pca_dictionary", "metric_pca_dictionary", "task_feature_weights", "feature_weights", "shrink_coefficients", "orient_nonneg", "normalise_dictionary",
           "check_dictionary_norms", "PCA_MAX_HALVINGS", "DICTIONARY_CONSTRAINTS", "check_dictionary_constraint",
           "constrained_dictionary_solver", "constrained_start"]

#: most halvings of a PCA start's coefficients tried by ``FactIRL(pca_shrink=True)`` (factor 2**-20)
PCA_MAX_HALVINGS = 20


def pca_dictionary(parameters: ArrayLike, n_components: int,
                   rng: np.random.Generator | int | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Principal directions of learnt task parameters, as a dictionary and coefficients.

    The factorial model ``theta_i = D h_i`` has no offset, so this is the uncentred PCA
    (truncated SVD) ``Theta ~ H D^T``: ``D`` holds the first ``n_components`` right singular
    vectors (orthonormal columns) and ``H = Theta D``. When Theta has fewer independent rows
    than components, the missing directions are random unit vectors orthogonal to the others.

    Parameters
    ----------
    parameters : array_like, shape (n, d)
        Learnt parameters of n tasks (e.g. flat rewards flattened).
    n_components : int
        k.
    rng : numpy.random.Generator or int or None
        Used only to complete a rank-deficient basis.

    Returns
    -------
    dictionary : ndarray, shape (d, k)
    coefficients : ndarray, shape (n, k)
    """
    X = check_array(parameters, "parameters", ndim=2)
    if X.shape[0] == 0:
        raise ValidationError(f"parameters must have shape (n, d) with n >= 1; got {X.shape}")
    n_components = check_int(n_components, "n_components", minimum=1)
    n, d = X.shape
    if n_components > d:
        raise ValidationError(f"n_components={n_components} exceeds the parameter dimension d={d}")
    _, s, Vt = np.linalg.svd(X, full_matrices=False)
    rank = int(np.sum(s > s[0] * 1e-10)) if s.size and s[0] > 0 else 0
    D = Vt[: min(rank, n_components)].T
    if D.shape[1] < n_components:
        extra = as_rng(rng).standard_normal((d, n_components - D.shape[1]))
        Qm, _ = np.linalg.qr(np.hstack([D, extra]))
        D = Qm[:, :n_components]
    return D, X @ D


def feature_weights(features: Any, rewards: NDArray[np.float64]) -> NDArray[np.float64]:
    """Minimum-norm least-squares weights ``W`` with ``Phi W ~ X``: rewards mapped back to feature space.

    Parameters
    ----------
    features : ndarray, shape (S*A, p), or StateBroadcast
        ``Phi``. For a :class:`~factirl_opt.tasks.features.StateBroadcast` the solution is the
        mean over the actions (:func:`factirl_opt.tasks.basis.least_squares_weights`).
    rewards : ndarray, shape (S*A, m)
        ``X``, one column per reward.

    Returns
    -------
    ndarray, shape (p, m)
    """
    return least_squares_weights(features, rewards)


def metric_pca_dictionary(weights: ArrayLike, features: TaskFeatures, n_components: int,
                          rng: np.random.Generator | int | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The PCA start of feature weights of tasks in several environments (docs/maths.md §8).

    With one feature matrix ``Phi`` the start is the PCA of the rewards ``Phi w_i``, which is
    the PCA of the weights in the metric ``G = Phi^T Phi``. With per-task features ``Phi_i``
    the metric is their mean Gram matrix ``G = mean_i Phi_i^T Phi_i`` (state features counted
    once per action): ``D`` (p, k) and ``H`` (n, k) come from the uncentred PCA of
    ``W G^{1/2}`` mapped back by the minimum-norm pre-image, so ``G^{1/2} D`` has orthonormal
    columns and ``H = W G D`` (:meth:`factirl_opt.tasks.basis.TaskBasis.start_dictionary`).
    When every task has the same features this is the shared start, up to the signs of the
    primitives.

    Parameters
    ----------
    weights : array_like, shape (n, p)
        The flat learner's feature weights.
    features : TaskFeatures
    n_components : int
        k, at most the rank of ``G``.
    rng : numpy.random.Generator or int or None
        Used only to complete a rank-deficient basis.

    Returns
    -------
    dictionary : ndarray, shape (p, k)
    coefficients : ndarray, shape (n, k)
    """
    return TaskBasis(features).start_dictionary(weights, n_components, rng, pca_dictionary)


def task_feature_weights(features: TaskFeatures, rewards: Any) -> NDArray[np.float64]:
    """Minimum-norm least-squares weights ``w_i`` with ``Phi_i w_i ~ R_i`` (n, p), one task at a time.

    ``rewards`` is a stacked (n, S, A) array or a list of (S_i, A) arrays.
    """
    return TaskBasis(features).start_points_from_rewards(rewards, features.n_tasks)


def shrink_coefficients(total_loss: Callable[[np.ndarray], Any], coefficients: ArrayLike,
                        max_halvings: int = PCA_MAX_HALVINGS) -> tuple[NDArray[np.float64], int, int]:
    """Halve a start's coefficients while the total loss decreases.

    A flat learner fitted to near-deterministic demonstrations grows rewards far larger than
    the expert's; their rank-k truncation (the PCA start) then lies where the Boltzmann policies
    are saturated and the gradients of eq. (10) nearly vanish, so descent from it crawls
    (Objectworld at 32x32: the rank-5 truncation scores a policy-matching loss of 6.50 over 10
    tasks, 4.77 at 1/32 of its scale, 8.0 at zero). Scaling ``H`` by ``2**-j`` leaves the
    primitives unchanged; ``j`` is the number of halvings that each lowered the loss (the next
    one did not; ``j = 0``, the unscaled start, when halving does not help).

    Parameters
    ----------
    total_loss : callable
        ``total_loss(H) -> float`` (or an array, summed): the objective of eq. (10) at
        coefficients H (n, k).
    coefficients : ndarray, shape (n, k)
    max_halvings : int
        Largest j tried.

    Returns
    -------
    coefficients : ndarray, shape (n, k)
        ``2**-j H``.
    halvings : int
        j.
    n_calls : int
        Calls of ``total_loss`` (batched planning evaluations).

    Raises
    ------
    FitInterrupted
        On a KeyboardInterrupt (or lost workers); its ``result`` is ``(2**-j H, j, n_calls, total_loss(2**-j H))``
        for the best j found so far (the loss is None when the first call was interrupted).
    """
    H = np.asarray(coefficients, dtype=float)
    best, j, calls = None, 0, 0
    try:
        best, calls = total_loss(H), 1
        while j < max_halvings:
            trial = total_loss(H * 2.0 ** -(j + 1))
            calls += 1
            if not float(np.sum(trial)) < float(np.sum(best)):
                break
            best, j = trial, j + 1
    except INTERRUPTIONS as exc:
        raise FitInterrupted((H * 2.0 ** -j, j, calls, best), "shrink_coefficients") from exc
    return H * 2.0 ** -j, j, calls


def orient_nonneg(D: NDArray[np.float64], H: NDArray[np.float64],
                  fold: bool = False) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Prepare an initialisation for a nonnegative H-step (the model ``H D^T`` is unchanged).

    The sign of each primitive is arbitrary (``D[:, l] -> -D[:, l]``, ``H[:, l] -> -H[:, l]``);
    flip the primitives whose coefficients sum to a negative value, so that projecting H onto
    ``H >= 0`` keeps most of each primitive's mass instead of zeroing it. With ``fold`` (the
    random initialisation, whose H is a fresh draw) take ``|H|`` instead.

    Parameters
    ----------
    D : ndarray, shape (p, k)
    H : ndarray, shape (n, k)
    fold : bool

    Returns
    -------
    D, H : ndarray, shapes (p, k) and (n, k)
    """
    if fold:
        return D, np.abs(H)
    sign = np.where(H.sum(axis=0) < 0, -1.0, 1.0)
    return D * sign, H * sign


#: relative slack of :func:`normalise_dictionary`'s band edges (far above round-off, far below any real change)
BAND_SLACK = 1e-9


def normalise_dictionary(D: NDArray[np.float64], H: NDArray[np.float64],
                         band: float = 2.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rescale the primitives to unit norm (H rescaled to match) once one leaves a band.

    The model is invariant to ``D -> D diag(c), H -> H diag(1/c)``; keeping the columns of D
    near unit norm keeps the two sub-problems balanced. Rescaling only when a norm leaves
    ``[1/band, band]`` avoids perturbing the product (in floating point) at every iteration;
    ``band=1`` rescales always (a sparse H-step's L1 penalty is only meaningful for primitives
    of fixed norm, so its fits keep ``||D[:, l]|| = 1``). The band's edges are widened by a
    relative :data:`BAND_SLACK`, so that a norm at an edge up to round-off (state rewards give
    ``1/sqrt(A)``, exactly ``1/band`` for four actions) takes the same branch whichever route
    computed it.

    Parameters
    ----------
    D : ndarray, shape (p, k)
    H : ndarray, shape (n, k)
    band : float
        Rescale when a column norm leaves ``[1/band, band]``; ``np.inf`` never rescales.

    Returns
    -------
    D, H : ndarray, shapes (p, k) and (n, k)
        ``D diag(1/c)`` and ``H diag(c)`` with ``c`` the column norms (zero columns kept), or
        the inputs unchanged.
    """
    norms = np.linalg.norm(D, axis=0)
    low, high = (1.0 - BAND_SLACK) / band, (1.0 + BAND_SLACK) * band
    if band > 1 and np.all((norms >= low) & (norms <= high)):
        return D, H
    norms[norms == 0] = 1.0
    return D / norms, H * norms


def check_dictionary_norms(D: NDArray[np.float64], name: str = "dictionary") -> None:
    """Refuse a dictionary whose column norms overflow float64 when computed (it cannot be normalised).

    :func:`normalise_dictionary` divides the primitives by their norms and multiplies the
    coefficients by them: with an infinite norm the primitives would become zero and the
    coefficients infinite, a failure the fit would then blame on the coefficients.

    Parameters
    ----------
    D : ndarray, shape (p, k)
        Finite (already validated) dictionary.
    name : str
        How the error message names ``D`` (e.g. ``"init D0"``).

    Raises
    ------
    ValidationError
        When a column norm of ``D`` is not finite, naming ``name`` and its largest entry.
    """
    with np.errstate(over="ignore"):
        norms = np.linalg.norm(D, axis=0)
    if not np.all(np.isfinite(norms)):
        raise ValidationError(f"{name} is too large to normalise: the squared norms of its columns overflow float64 "
                              f"(largest |{name}| entry {np.max(np.abs(D)):.3g}); rescale it (D -> D c, H -> H / c "
                              f"gives the same rewards)")


#: the constraints of ``FactIRL(dictionary_constraint=...)`` (None: the paper's free dictionary)
DICTIONARY_CONSTRAINTS = ("nonneg", "sparse", "nonneg-sparse")


@dataclasses.dataclass(frozen=True, repr=False)
class DictionaryConstraint(ParameterGroup):
    """A constraint on the columns of FactIRL's dictionary, the primitives (docs/maths.md §8b).

    ``FactIRL(dictionary_constraint=...)`` takes one, or the name of a ``kind`` (its ``alpha``
    the default).

    Parameters
    ----------
    kind : {None, "nonneg", "sparse", "nonneg-sparse"}, default=None
        None: the paper's free dictionary. Otherwise every primitive has unit norm and is
        nonnegative (``"nonneg"``), penalised by ``alpha * n * ||D||_1`` (``"sparse"``, n the
        number of tasks), or both. The D-step is then projected/proximal Armijo descent
        (:class:`solvers.ProximalArmijoSolver`), the start is moved onto the constraint
        (:func:`constrained_start`), and ``loss_history_`` includes the penalty; the transfer is
        unchanged (the dictionary is fixed).
    alpha : float, default=0.01
        The L1 weight per task of a sparse kind (> 0 there; ignored otherwise). Formerly
        ``FactIRL(dictionary_alpha=...)``.
    """

    kind: str | None = None
    alpha: float = 0.01

    @classmethod
    def of(cls, value: Any) -> DictionaryConstraint:
        """The constraint a ``dictionary_constraint`` value names: a kind's name (or None) at the default ``alpha``."""
        if isinstance(value, cls):
            return value
        if value is None or isinstance(value, str):
            return cls(kind=value)
        raise ValidationError(f"dictionary_constraint must be a DictionaryConstraint, None or one of "
                              f"{DICTIONARY_CONSTRAINTS}; got {value!r:.80}")


def check_dictionary_constraint(constraint: Any) -> tuple[str | None, float]:
    """The validated ``(kind, alpha)`` of a FactIRL's ``dictionary_constraint``
    (a :class:`DictionaryConstraint`, a kind's name or None).

    Raises
    ------
    ValidationError
        When the kind is not None or one of :data:`DICTIONARY_CONSTRAINTS`, or ``alpha`` is
        not a finite number >= 0 (> 0 for a sparse kind).
    """
    group = DictionaryConstraint.of(constraint)
    constraint, alpha = group.kind, group.alpha
    if constraint is not None and not (isinstance(constraint, str) and constraint in DICTIONARY_CONSTRAINTS):
        raise ValidationError(f"dictionary_constraint must be None or one of {DICTIONARY_CONSTRAINTS}; got {constraint!r}")
    alpha = check_real(alpha, "dictionary_constraint.alpha", 0.0, None)
    if constraint is not None and constraint.endswith("sparse") and not alpha > 0:
        raise ValidationError(f"dictionary_constraint={constraint!r} needs alpha > 0 (the L1 weight); got {alpha!r}")
    return constraint, float(alpha)


def constrained_dictionary_solver(d_solver: solvers.StepSolver, constraint: str, alpha: float, n_params: int,
                                  n_primitives: int, n_tasks: int) -> solvers.StepSolver:
    """The D-step of a constrained dictionary (docs/maths.md §8b): proximal Armijo descent
    (:class:`solvers.ProximalArmijoSolver`) with the Armijo options of ``d_solver``, on unit-norm
    columns, nonnegative for ``"nonneg*"``, with the penalty ``alpha * n_tasks * ||D||_1`` for
    ``"*sparse"`` (per task, so one alpha means the same trade-off whatever the number of tasks).

    Parameters
    ----------
    d_solver : solvers.StepSolver
        The resolved D-solver: an unconstrained :class:`solvers.ArmijoSolver` (``"armijo"``).
    constraint : {"nonneg", "sparse", "nonneg-sparse"}
    alpha : float
    n_params, n_primitives, n_tasks : int
        p, k and n.

    Raises
    ------
    ValidationError
        When ``d_solver`` is not a plain Armijo solver (a projected or proximal step needs one).
    """
    if type(d_solver) is not solvers.ArmijoSolver or d_solver.nonneg:
        raise ValidationError(f"dictionary_constraint={constraint!r} takes projected/proximal Armijo steps on the "
                              f"dictionary: d_solver must be 'armijo' (options allowed); got {d_solver.name!r}")
    weight = alpha * n_tasks if constraint.endswith("sparse") else 0.0
    with translate_solver_errors():
        prox, penalty = solvers.unit_columns_prox(n_params, n_primitives, nonneg=constraint.startswith("nonneg"),
                                                  alpha=weight)
        options = {f: getattr(d_solver, f) for f in ("initial_step", "shrink", "grow", "c", "max_backtracks", "max_step")}
        return solvers.ProximalArmijoSolver(prox=prox, prox_penalty=penalty, **options)


def constrained_start(d_solver: solvers.StepSolver, D: NDArray[np.float64], H: NDArray[np.float64],
                      nonneg: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A start ``(D, H)`` moved onto a constrained dictionary's feasible set.

    The primitives are scaled to unit norm (``H`` rescaled: the rewards unchanged); for
    nonnegative columns each primitive's sign is chosen (with its coefficients') so that its
    positive part is the larger; then ``D`` is projected (``d_solver.project``: the positive
    part normalised, or the largest entry where nothing is positive). ``H`` is kept: the first
    H-step refits it.

    Parameters
    ----------
    d_solver : solvers.StepSolver
        From :func:`constrained_dictionary_solver`.
    D : ndarray, shape (p, k)
    H : ndarray, shape (n, k)
    nonneg : bool
        Whether the columns are nonnegative.

    Returns
    -------
    D, H : ndarray, shapes (p, k) and (n, k)
    """
    D, H = normalise_dictionary(D, H, band=1.0)
    if nonneg:
        sign = np.where(np.linalg.norm(np.maximum(-D, 0.0), axis=0) > np.linalg.norm(np.maximum(D, 0.0), axis=0), -1.0, 1.0)
        D, H = D * sign, H * sign
    return d_solver.project(D.reshape(1, -1)).reshape(D.shape), H
