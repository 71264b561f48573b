"""The reward basis of a fit: ``R_i = Phi_i w_i``, one type for every kind of reward features.

Whatever the features of a fit, its rewards are linear in per-task weights ``w_i`` (p,)
(docs/maths.md §7, §8). :class:`RewardBasis` is that linear map and everything the objectives,
the step problems and the learners need of it, so that no code below the estimators branches
on the kind of features:

- :class:`TabularBasis`: ``Phi`` the identity, tabular rewards ``R_i = w_i`` (p = S*A);
- :class:`StateBasis`: ``Phi = kron(I_S, 1_A)``, never formed, rewards of the states (p = S);
- :class:`SharedBasis`: one (S*A, p) matrix shared by every task;
- :class:`TaskBasis`: one (S_i*A, p) or (S_i, p) matrix per task, on its own environment.

A basis is always present (tabular rewards are a basis, never None). It offers:

- :attr:`RewardBasis.n_params`, the number of weights per task;
- :meth:`RewardBasis.rewards` and :meth:`RewardBasis.point_rewards`: rewards from weights of
  chosen rows (the latter refused when the planner would overflow on them);
- :meth:`RewardBasis.pull`: the adjoint ``Phi_i^T y_i`` for chosen rows (the chain rule from
  ``y_i = dJ_i/dR_i``); :meth:`RewardBasis.jacobian_features`: the features a least-squares
  Jacobian is taken along;
- :meth:`RewardBasis.compose`: the basis ``Phi_i D`` of a dictionary (the H-step, eq. 12), and
  the dictionary's own products (:meth:`RewardBasis.dictionary_rewards`,
  :meth:`RewardBasis.dictionary_gradient`, eq. 11; :meth:`RewardBasis.factorial_gradients`);
- :meth:`RewardBasis.dense` (dense rows), :meth:`RewardBasis.subset` (a row subset) and
  :meth:`RewardBasis.digest` (what a model records of the features);
- the PCA start of the factorial model in the basis' own metric
  (:meth:`RewardBasis.start_points`, :meth:`RewardBasis.start_dictionary`).

Each implementation keeps the arithmetic its kind always had (the same products in the same
order), so a fit gives the same bits whatever code path carries the basis. A new kind of
features (low-rank, sparse, ...) is one more subclass: the learners and objectives take it
unchanged.
"""

from __future__ import annotations

import abc
import functools
import hashlib
import inspect
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._batched import rows_matmul
from .._validation import check_array
from ..exceptions import ValidationError
from .features import StateBroadcast, TaskFeatures, check_reward_scale, linear_rewards

__all__ = ["RewardBasis", "check_basis", "CHECKED_METHODS", "TabularBasis", "StateBasis", "SharedBasis", "TaskBasis", "ComposedBasis", "as_basis", "features_matrix", "matrix_digest", "least_squares_weights",
           "PCA", "WEIGHT_NAMES", "DICTIONARY_NAMES"]

#: ``pca(X, k, rng) -> (D, H)``: the uncentred PCA the factorial start uses (``learners.dictionary.pca_dictionary``)
PCA = Callable[[NDArray[np.float64], int, Any], tuple[NDArray[np.float64], NDArray[np.float64]]]

WEIGHT_NAMES = ("features", "weights")
DICTIONARY_NAMES = ("features @ dictionary", "coefficients")


def matrix_digest(features: NDArray[np.float64]) -> str:
    """SHA-256 (hex) of a validated (S*A, p) feature matrix as float64, shape included."""
    F = np.ascontiguousarray(features, dtype=np.float64)
    h = hashlib.sha256(repr(F.shape).encode())
    h.update(F.tobytes())
    return h.hexdigest()


class RewardBasis(abc.ABC):
    """What rewards are linear in: ``R_i = Phi_i w_i`` for the rows (tasks) ``i`` (module docstring).

    Rows index the tasks of the fit. A basis shared by every task (tabular, state, one
    matrix; :attr:`shared`) takes any rows; a per-task basis (:class:`TaskBasis`) has one
    ``Phi_i`` per row. Per-task arrays (rewards, ``dJ/dR``) are stacked (r, S, A) arrays, or
    lists of (S_i, A) arrays when the tasks' environments differ in size.

    A new kind of features subclasses this and implements :attr:`n_params`, :attr:`n_actions`,
    :meth:`rewards`, :meth:`pull`, :meth:`dense` and :meth:`check_environments`; every other
    operation has a default in terms of those (the built-in kinds override them with the
    products they always used, for the same bits).

    Attributes
    ----------
    n_params : int
        p, the weights per task.
    n_actions : int
    shared : bool
        Whether one ``Phi`` serves every row (else one per task, in task order).
    names : (str, str)
        What ``Phi`` and ``w`` are called in the message of an overflow.
    """

    n_params: int
    n_actions: int
    shared: bool = True
    names: tuple[str, str] = WEIGHT_NAMES

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A kind defined outside the library has what its methods return checked where it enters
        the library (:func:`check_basis`, :data:`CHECKED_METHODS`); the built-in kinds validate their
        features once, when they are built, and are not wrapped (their products of checked inputs
        can only overflow, which :func:`~factirl_opt.tasks.features.check_reward_scale` reports)."""
        super().__init_subclass__(**kwargs)
        if cls.__module__.split(".")[0] == __name__.split(".")[0] and cls.__module__ != "__main__":
            return
        for name, check in CHECKED_METHODS.items():
            method = cls.__dict__.get(name)
            if callable(method) and not getattr(method, "_checked_by_basis", False):
                setattr(cls, name, _checked(method, check))

    # -- what every kind implements ----------------------------------------------------------------
    @abc.abstractmethod
    def rewards(self, weights: ArrayLike, rows: ArrayLike | None = None, names: tuple[str, str] | None = None) -> Any:
        """Rewards ``Phi_i w_i`` of weights (r, p) of tasks ``rows`` (all tasks when None).

        Also reward *directions* (the products of a Jacobian-vector product). An overflow
        of float64 is a ValidationError naming the inputs (``names``, default :attr:`names`).
        """

    @abc.abstractmethod
    def pull(self, grads: Any, rows: ArrayLike | None = None) -> NDArray[np.float64]:
        """The adjoint ``Phi_i^T y_i`` (r, p) of reward gradients ``y_i`` (S_i, A) of tasks ``rows``."""

    @abc.abstractmethod
    def dense(self, rows: ArrayLike | None = None) -> list[NDArray[np.float64]]:
        """``Phi_i`` of ``rows`` as dense (S_i*A, p) matrices (a shared basis: one per row, or one
        when ``rows`` is None)."""

    @abc.abstractmethod
    def check_environments(self, n_states: Any, n_actions: int) -> None:
        """Raise :class:`~factirl_opt.exceptions.ValidationError` unless the basis fits tasks on
        environments of ``n_states`` (one S_i per task) states and ``n_actions`` actions."""

    # -- defaults in terms of the above ------------------------------------------------------------
    def point_rewards(self, weights: ArrayLike, rows: ArrayLike | None, limit: float,
                      names: tuple[str, str] | None = None) -> Any:
        """:meth:`rewards` at a point the planner evaluates, refused (ValidationError) when their
        largest magnitude reaches ``limit`` (:func:`~factirl_opt.tasks.features.check_reward_scale`)."""
        names = _names(names, self.names)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported, naming the inputs
            R = self.rewards(weights, rows, names)
        return check_reward_scale(R, limit, self.dense(rows), weights, names)

    def jacobian_features(self, rows: ArrayLike | None = None) -> Any:
        """The features a least-squares Jacobian is taken along (``residual_jacobian``'s last
        argument): one (S*A, p) matrix for a shared basis, else one per row."""
        return self.dense()[0] if self.shared else self.dense(rows)

    def recorded_features(self, rows: ArrayLike) -> list[NDArray[np.float64] | None]:
        """``Phi_i`` of ``rows`` as a record of one task keeps them (a transfer posterior,
        :class:`~factirl_opt.learners.posterior.LaplacePosterior`): dense (S_i*A, p) matrices
        (:meth:`dense`), or None where ``Phi`` is the identity (tabular rewards: nothing to keep)."""
        return list(self.dense(rows))

    def subset(self, rows: ArrayLike) -> RewardBasis:
        """The basis of the tasks ``rows`` only (a shared basis is its own subset)."""
        if not self.shared:
            raise NotImplementedError(f"{type(self).__name__} defines no row subset")
        return self

    def digest(self) -> str | None:
        """What a model records of its features (``features_sha256_``): the SHA-256 of the one
        matrix given, None for tabular or state rewards, per-task features and other kinds."""
        return None

    # -- a dictionary: R_i = Phi_i D h_i (docs/maths.md §8) -----------------------------------------
    def compose(self, dictionary: NDArray[np.float64]) -> RewardBasis:
        """The basis ``Phi_i D`` (p, k) -> k weights per task: the features of the H-step (eq. 12)."""
        return ComposedBasis(self, dictionary)

    def factorial_rewards(self, dictionary: NDArray[np.float64], coefficients: NDArray[np.float64]) -> Any:
        """Every task's ``R_i = Phi_i D h_i`` from D (p, k) and H (n, k); an overflow names the inputs."""
        return self.compose(dictionary).rewards(coefficients, names=DICTIONARY_NAMES)

    def dictionary_rewards(self, dictionary: NDArray[np.float64], coefficients: NDArray[np.float64]) -> Any:
        """``Phi_i D h_i`` as the dictionary step forms them (also directions ``dD``)."""
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported by the check
            return self.rewards(coefficients @ dictionary.T)

    def check_dictionary_rewards(self, rewards: Any, dictionary: NDArray[np.float64],
                                 coefficients: NDArray[np.float64], limit: float) -> Any:
        """:meth:`dictionary_rewards` at a point, refused when the planner would overflow on them."""
        return check_reward_scale(rewards, limit, self.dense(), coefficients @ dictionary.T,
                                  ("features", "dictionary @ coefficients"))

    def dictionary_gradient(self, grads: Any, coefficients: NDArray[np.float64]) -> NDArray[np.float64]:
        """``sum_i Phi_i^T y_i h_i^T`` (p, k) over every task (eq. 11)."""
        return self.pull(grads).T @ coefficients

    def factorial_gradients(self, grads: Any, dictionary: NDArray[np.float64],
                            coefficients: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(dJ/dH, dJ/dD)`` = ``([D^T Phi_i^T y_i], sum_i Phi_i^T y_i h_i^T)`` (eqs. 11-12)."""
        G = self.pull(grads)
        return G @ dictionary, G.T @ coefficients

    def point_pull(self, grads: Any) -> NDArray[np.float64]:
        """``[Phi_i^T y_i]`` (n, p) of every task, as a shard returns it for the factorial loop's
        optimality measure (``dJ/dH = G D``, ``dJ/dD = G^T H``)."""
        return self.pull(grads)

    # -- the PCA start of the factorial model ---------------------------------------------------------
    def start_points(self, weights: NDArray[np.float64]) -> NDArray[np.float64]:
        """What the PCA start decomposes (n, d), from flat weights (n, p): the flat rewards
        (n, S*A) of the built-in shared kinds, the weights themselves otherwise (then
        :meth:`start_dictionary` works in the basis' metric)."""
        return weights

    def start_points_from_rewards(self, rewards: Any, n_tasks: int) -> NDArray[np.float64]:
        """:meth:`start_points` of flat rewards given by the user ((n, S, A), or a list of (S_i, A)),
        through their least-squares weights; a ValidationError names a wrong shape."""
        return self.start_points(self.weights_from_rewards(rewards, n_tasks))

    def weights_from_rewards(self, rewards: Any, n_tasks: int) -> NDArray[np.float64]:
        """The least-squares weights (n, p) of flat rewards ((n, S, A), or a list of (S_i, A)):
        ``argmin_w ||Phi_i w - R_i||`` per task (exact where ``R_i`` is in the basis' span, as the
        rewards of a flat fit on this basis are); a ValidationError names a wrong shape."""
        if len(rewards) != n_tasks:
            raise ValidationError(f"flat_rewards must hold one (S_i, A) array per task ({n_tasks}); got {len(rewards)}")
        out = np.empty((n_tasks, self.n_params))
        for i, (F, R) in enumerate(zip(self.dense(np.arange(n_tasks)), rewards)):
            R = check_array(R, f"flat_rewards[{i}] (task {i})")
            shape = (F.shape[0] // self.n_actions, self.n_actions)
            if R.shape != shape:
                raise ValidationError(f"flat_rewards of task {i} must have shape (S_i, A) = {shape} (its MDP); got {R.shape}")
            out[i] = np.linalg.lstsq(F, R.reshape(-1), rcond=None)[0]
        return out

    def gram(self, n_tasks: int) -> NDArray[np.float64]:
        """The metric of the PCA start: ``mean_i Phi_i^T Phi_i`` (p, p) over ``n_tasks`` tasks."""
        G = np.zeros((self.n_params, self.n_params))
        for F in self.dense(np.arange(n_tasks)):
            G += F.T @ F
        return G / n_tasks

    def rank(self, n_tasks: int) -> int:
        """The reward directions the basis spans over ``n_tasks`` tasks: the rank of :meth:`gram`
        (at most ``n_params``), the most primitives a PCA start (:meth:`start_dictionary`)
        can have. A sharing search caps its candidate k at it."""
        return int(_spanned(np.linalg.eigvalsh(self.gram(n_tasks))).sum())

    def start_dictionary(self, points: NDArray[np.float64], n_components: int, rng: Any,
                         pca: PCA) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The PCA start ``(D, H)`` ((p, k), (n, k)) of :meth:`start_points`, in the basis' metric.

        By default the PCA of the weights in the metric ``G`` (:meth:`gram`): the uncentred PCA
        of ``W G^{1/2}`` mapped back by the minimum-norm pre-image, so ``G^{1/2} D`` has
        orthonormal columns and ``H = W G D`` (the PCA of the rewards ``Phi_i w_i``).
        """
        W = check_array(points, "weights", ndim=2)
        return _metric_pca(W, self.gram(W.shape[0]), n_components, rng, pca)


def _spanned(eigenvalues: NDArray[np.floating]) -> NDArray[np.bool_]:
    """Which eigenvalues of a Gram matrix count as spanned directions (relative to the largest, 1e-12)."""
    return eigenvalues > max(float(eigenvalues.max()), 0.0) * 1e-12


def _metric_pca(W: NDArray[np.float64], G: NDArray[np.float64], n_components: int, rng: Any,
                pca: PCA) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The uncentred PCA of weights W (n, p) in the metric G (p, p) (:meth:`RewardBasis.start_dictionary`)."""
    e, V = np.linalg.eigh(G)
    keep = _spanned(e)
    if int(keep.sum()) < n_components:
        raise ValidationError(f"n_components={n_components} exceeds the rank {int(keep.sum())} of the features' mean "
                              "Gram matrix: the features span fewer reward directions than primitives")
    root = np.sqrt(e[keep])
    Dr, H = pca(W @ (V[:, keep] * root), n_components, rng)
    return V[:, keep] @ (Dr / root[:, None]), H


# -- the boundary: what a basis defined outside the library returns ----------------------------------


def check_basis(basis: RewardBasis) -> RewardBasis:
    """``basis`` if its declared sizes are usable: ``n_params`` and ``n_actions`` integers >= 1.

    Called where a basis given as ``features`` enters a fit (:func:`~factirl_opt.tasks.task_set.reward_basis`).
    What its methods return is checked on every call (:data:`CHECKED_METHODS`) for a kind defined
    outside the library.

    Raises
    ------
    ValidationError
        Naming the basis class and the attribute, e.g. ``n_params = '5'`` (a str).
    """
    for attr in ("n_params", "n_actions"):
        value = getattr(basis, attr, None)
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValidationError(f"{type(basis).__name__}.{attr} must be an integer >= 1; got {value!r:.60} "
                                  f"({type(value).__name__})")
    return basis


def _where(basis: RewardBasis, method: str) -> str:
    return f"{type(basis).__name__}.{method}()"


def _real_array(basis: RewardBasis, method: str, what: str, value: Any) -> NDArray[Any]:
    """``value`` if it is a numpy array of real floating-point numbers, else a ValidationError."""
    if not isinstance(value, np.ndarray):
        raise ValidationError(f"{_where(basis, method)} must return {what} as numpy arrays; got {type(value).__name__} "
                              f"{value!r:.60}")
    if value.dtype.kind != "f":
        raise ValidationError(f"{_where(basis, method)} must return {what} of real floating-point numbers; got dtype "
                              f"{value.dtype}")
    return value


def _recorded_states(basis: RewardBasis, rows: Any, r: int) -> list[int] | None:
    """The S_i of ``rows`` from the environments the basis last accepted (:meth:`RewardBasis.check_environments`)."""
    S = basis.__dict__.get("_checked_states")
    if S is None:
        return None
    if S.size == 1 or basis.shared:
        return [int(S[0])] * r
    idx = np.arange(S.size) if rows is None else np.asarray(rows).reshape(-1)
    if idx.size != r or (idx.size and (idx.min() < -S.size or idx.max() >= S.size)):
        return None
    return [int(S[i]) for i in idx]


def _not_finite(basis: RewardBasis, method: str, what: str, inputs: Any, out: Any, rows: Any) -> None:
    """A non-finite output of finite inputs: a ValidationError, unless ``|inputs| x |features|`` could
    overflow (then the caller's overflow check names the inputs, as for a built-in kind)."""
    big_in = max((float(np.max(np.abs(x), initial=0.0)) for x in inputs), default=0.0)
    if not np.isfinite(big_in):
        return  # non-finite inputs: the caller's business
    dense = basis.dense(rows) if method != "dense" else []  # checked: NaN rows are reported as such
    big_f = max((float(np.max(np.abs(F), initial=0.0)) for F in dense), default=1.0)
    width = max((F.shape[0] + F.shape[1] for F in dense), default=1)
    if big_in * big_f * width < np.finfo(np.float64).max / 4:
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(out))[0])
        raise ValidationError(f"{_where(basis, method)} returned {what} that are not finite ({float(out[bad])!r} at index "
                              f"{bad}) for finite inputs whose products cannot overflow (largest |input| = "
                              f"{big_in:.3g}, largest |feature| = {big_f:.3g})")


def _check_rewards(basis: RewardBasis, out: Any, weights: Any, rows: Any = None, names: Any = None) -> Any:
    """What ``rewards(weights, rows)`` returned: one (S_i, A, ...) array per row (stacked, or a list), real, finite."""
    W = np.asarray(weights)
    r, trail = (W.shape[0], W.shape[2:]) if W.ndim >= 2 else (1, ())
    parts = list(out) if isinstance(out, (list, tuple)) else [_real_array(basis, "rewards", "rewards", out)]
    if isinstance(out, (list, tuple)):
        parts = [_real_array(basis, "rewards", "rewards", x) for x in parts]
        if len(parts) != r:
            raise ValidationError(f"{_where(basis, 'rewards')} must return one (S_i, A) array per row of the weights "
                                  f"({r}); got {len(parts)}")
        shapes = [x.shape for x in parts]
    else:
        if parts[0].ndim != 3 + len(trail) or len(parts[0]) != r:
            raise ValidationError(f"{_where(basis, 'rewards')} must return rewards of shape (r, S, A{', ...' if trail else ''}) "
                                  f"= ({r}, S, {basis.n_actions}{''.join(f', {t}' for t in trail)}) for weights of shape "
                                  f"{W.shape}; got shape {parts[0].shape}")
        shapes = [x.shape for x in parts[0]]
    states = _recorded_states(basis, rows, r)
    for i, shape in enumerate(shapes):
        expected = ((states[i] if states else shape[0]), basis.n_actions, *trail)
        if tuple(shape) != expected:
            raise ValidationError(f"{_where(basis, 'rewards')} must return rewards of shape (S_i, A) = "
                                  f"{expected[:2]} per row{' (the environments it was given)' if states else ''}; row "
                                  f"{i} has shape {tuple(shape)}")
    for x in parts:
        if not np.all(np.isfinite(x)):
            _not_finite(basis, "rewards", "rewards", [W], x, rows)
    return out


def _check_pull(basis: RewardBasis, out: Any, grads: Any, rows: Any = None) -> Any:
    """What ``pull(grads, rows)`` returned: (r, p) real and finite."""
    out = _real_array(basis, "pull", "weight gradients", out)
    r = len(grads)
    if out.shape != (r, basis.n_params):
        raise ValidationError(f"{_where(basis, 'pull')} must return shape (r, p) = ({r}, {basis.n_params}) for {r} "
                              f"rows of reward gradients; got {out.shape}")
    if not np.all(np.isfinite(out)):
        _not_finite(basis, "pull", "weight gradients", [np.asarray(g) for g in grads], out, rows)
    return out


def _check_dense(basis: RewardBasis, out: Any, rows: Any = None) -> Any:
    """What ``dense(rows)`` returned: one (S_i*A, p) matrix per row (one for a shared basis and no rows), real, finite."""
    if not isinstance(out, (list, tuple)):
        raise ValidationError(f"{_where(basis, 'dense')} must return a list of (S_i*A, p) arrays; got "
                              f"{type(out).__name__}")
    if rows is not None and len(out) != np.asarray(rows).size:
        raise ValidationError(f"{_where(basis, 'dense')} must return one matrix per row ({np.asarray(rows).size}); "
                              f"got {len(out)}")
    states = _recorded_states(basis, rows, len(out))
    seen: set[int] = set()
    for i, F in enumerate(out):
        F = _real_array(basis, "dense", "dense rows", F)
        rows_i = states[i] * basis.n_actions if states else (F.shape[0] if F.ndim == 2 and F.shape[0] % basis.n_actions == 0 else -1)
        if F.ndim != 2 or F.shape != (rows_i, basis.n_params):
            raise ValidationError(f"{_where(basis, 'dense')} must return (S_i*A, p) matrices with p = {basis.n_params}"
                                  f"{f' and S_i*A = {rows_i}' if rows_i > 0 else f', S_i*A a multiple of A = {basis.n_actions}'}; "
                                  f"matrix {i} has shape {F.shape}")
        if id(F) in seen:  # one matrix repeated for every row (a shared basis): checked once
            continue
        seen.add(id(F))
        if not np.all(np.isfinite(F)):
            bad = tuple(int(j) for j in np.argwhere(~np.isfinite(F))[0])
            raise ValidationError(f"{_where(basis, 'dense')} returned dense rows that are not finite ({float(F[bad])!r} at "
                                  f"index {bad} of matrix {i})")
    return out


def _check_environments(basis: RewardBasis, out: Any, n_states: Any, n_actions: int) -> Any:
    """After ``check_environments`` accepted them: the environments' S_i, against which rewards and dense
    rows are checked."""
    try:
        basis.__dict__["_checked_states"] = np.asarray(n_states).reshape(-1).astype(np.int64)
    except (AttributeError, TypeError, ValueError):  # no instance dictionary: the shapes are checked without S_i
        pass
    return out


#: the methods of a basis defined outside the library whose results are checked on every call
#: (:meth:`RewardBasis.__init_subclass__`): each maps to ``check(basis, result, *args)``
CHECKED_METHODS: dict[str, Callable[..., Any]] = {"rewards": _check_rewards, "pull": _check_pull, "dense": _check_dense,
                                                  "check_environments": _check_environments}


def _checked(method: Callable[..., Any], check: Callable[..., Any]) -> Callable[..., Any]:
    """``method`` followed by ``check(self, result, *args)`` (the arguments bound by name)."""
    signature = inspect.signature(method)
    n_args = len(inspect.signature(check).parameters) - 2  # what the check reads after (basis, result)

    @functools.wraps(method)
    def checked(self: RewardBasis, *args: Any, **kwargs: Any) -> Any:
        out = method(self, *args, **kwargs)
        try:
            bound = signature.bind(self, *args, **kwargs)
        except TypeError:
            return out
        bound.apply_defaults()
        values = list(bound.arguments.values())[1:]
        return check(self, out, *values[:n_args])

    checked._checked_by_basis = True  # type: ignore[attr-defined]
    return checked


class ComposedBasis(RewardBasis):
    """The basis ``Phi_i D`` of a basis and a dictionary D (p, k): weights ``h_i`` (k,), ``R_i = Phi_i D h_i``
    (the default :meth:`RewardBasis.compose`)."""

    names = DICTIONARY_NAMES

    def __init__(self, base: RewardBasis, dictionary: NDArray[np.float64]) -> None:
        self.base, self.dictionary = base, np.asarray(dictionary, dtype=np.float64)
        self.n_params, self.n_actions, self.shared = self.dictionary.shape[1], base.n_actions, base.shared

    def rewards(self, weights, rows=None, names=None):
        W = np.asarray(weights, dtype=np.float64)
        return self.base.rewards(np.einsum("pk,rk...->rp...", self.dictionary, W), rows, _names(names, self.names))

    def pull(self, grads, rows=None):
        return self.base.pull(grads, rows) @ self.dictionary

    def dense(self, rows=None):
        return [F @ self.dictionary for F in self.base.dense(rows)]

    def check_environments(self, n_states, n_actions):
        self.base.check_environments(n_states, n_actions)

    def subset(self, rows):
        return ComposedBasis(self.base.subset(rows), self.dictionary)


def _names(names: tuple[str, str] | None, default: tuple[str, str]) -> tuple[str, str]:
    return default if names is None else names


class TabularBasis(RewardBasis):
    """Tabular rewards: ``Phi`` the identity (S*A, S*A), ``R_i = w_i`` reshaped (p = S*A)."""

    names = ("dictionary", "coefficients")

    def __init__(self, n_states: int, n_actions: int) -> None:
        self.n_states, self.n_actions = int(n_states), int(n_actions)
        self.n_params = self.n_states * self.n_actions

    def check_environments(self, n_states, n_actions):
        _check_one_environment(self, n_states, n_actions, "tabular rewards are defined on one MDP")

    def rewards(self, weights, rows=None, names=None):
        return np.asarray(weights).reshape(-1, self.n_states, self.n_actions)

    def point_rewards(self, weights, rows, limit, names=None):
        return self.rewards(weights, rows)

    def pull(self, grads, rows=None):
        return np.asarray(grads).reshape(len(grads), self.n_params)

    def jacobian_features(self, rows=None):
        return np.eye(self.n_params)

    def rank(self, n_tasks):
        return self.n_params

    def dense(self, rows=None):
        n = 1 if rows is None else np.asarray(rows).size
        return [np.eye(self.n_params)] * n

    def recorded_features(self, rows):
        return [None] * np.asarray(rows).size

    def compose(self, dictionary):
        return SharedBasis._product(np.asarray(dictionary, dtype=np.float64), self.n_states, self.n_actions,
                                    ("dictionary", "coefficients"))

    def factorial_rewards(self, dictionary, coefficients):
        return linear_rewards(dictionary, coefficients, self.n_states, self.n_actions, ("dictionary", "coefficients"))

    def dictionary_rewards(self, dictionary, coefficients):
        return linear_rewards(dictionary, coefficients, self.n_states, self.n_actions, ("dictionary", "coefficients"))

    def check_dictionary_rewards(self, rewards, dictionary, coefficients, limit):
        return check_reward_scale(rewards, limit, dictionary, coefficients, ("dictionary", "coefficients"))

    def dictionary_gradient(self, grads, coefficients):
        H = np.asarray(coefficients, dtype=np.float64)
        return grads.reshape(H.shape[0], self.n_params).T @ H

    def factorial_gradients(self, grads, dictionary, coefficients):
        Y = grads.reshape(coefficients.shape[0], -1)
        return Y @ dictionary, Y.T @ coefficients

    def point_pull(self, grads):
        return grads.reshape(len(grads), -1)

    def start_points(self, weights):
        return self.rewards(weights).reshape(len(weights), -1)

    def start_points_from_rewards(self, rewards, n_tasks):
        return _flat_reward_rows(rewards, n_tasks, self.n_states, self.n_actions)

    def start_dictionary(self, points, n_components, rng, pca):
        return pca(points, n_components, rng)


def _check_one_environment(basis: Any, n_states: Any, n_actions: int, what: str) -> None:
    """Refuse environments other than the ``(n_states, n_actions)`` of a basis made for one MDP."""
    S = np.asarray(n_states).reshape(-1)
    if n_actions != basis.n_actions or np.any(S != basis.n_states):
        raise ValidationError(f"{what}: the basis is for S = {basis.n_states} states and A = {basis.n_actions} "
                              f"actions; got environments of S = {sorted(set(S.tolist()))} and A = {n_actions}")


def _flat_reward_rows(rewards: Any, n: int, S: int, A: int) -> NDArray[np.float64]:
    Theta = check_array(rewards, "flat_rewards")
    if Theta.shape != (n, S, A):
        raise ValidationError(f"flat_rewards must have shape (n, S, A) = ({n}, {S}, {A}); got {Theta.shape}")
    return Theta.reshape(n, -1)


class SharedBasis(RewardBasis):
    """One feature matrix ``Phi`` (S*A, p) shared by every task: ``R_i = Phi w_i``.

    Parameters
    ----------
    features : ndarray, shape (S*A, p)
        Validated (state features already repeated over the actions).
    n_states, n_actions : int
    names : (str, str), default=("features", "weights")
        For the message of an overflow (e.g. ``("features @ dictionary", "coefficients")``
        for a composed basis).
    digest : str, optional
        The digest a model records (:meth:`digest`); default that of ``features``.
    """

    def __init__(self, features: Any, n_states: int, n_actions: int, names: tuple[str, str] = WEIGHT_NAMES,
                 digest: str | None = None) -> None:
        if not isinstance(features, StateBroadcast):
            features = check_array(features, f"{type(self).__name__}: the {names[0]}", ndim=2)
            if features.shape[0] != int(n_states) * int(n_actions) or features.shape[1] < 1:
                raise ValidationError(f"{type(self).__name__}: the {names[0]} must have shape (S*A, p) = "
                                      f"({int(n_states) * int(n_actions)}, p >= 1); got {features.shape}")
        self._set(features, n_states, n_actions, names, digest)

    def _set(self, features: Any, n_states: int, n_actions: int, names: tuple[str, str], digest: str | None) -> None:
        self.features = features if isinstance(features, StateBroadcast) else np.asarray(features, dtype=np.float64)
        self.n_states, self.n_actions = int(n_states), int(n_actions)
        self.n_params = int(self.features.shape[1])
        self.names = names
        self._digest = digest

    @classmethod
    def _product(cls, features: NDArray[np.float64], n_states: int, n_actions: int,
                 names: tuple[str, str]) -> SharedBasis:
        """The basis of a product the library formed from checked inputs (``features @ D``): not checked
        again, so that an overflow in it is reported as one, where it is used."""
        basis = cls.__new__(cls)
        basis._set(features, n_states, n_actions, names, None)
        return basis

    def check_environments(self, n_states, n_actions):
        _check_one_environment(self, n_states, n_actions, "one shared feature matrix cannot fit every environment")

    def rank(self, n_tasks):
        if isinstance(self.features, StateBroadcast):
            return self.n_params
        return int(_spanned(np.linalg.eigvalsh(self.features.T @ self.features)).sum())

    def rewards(self, weights, rows=None, names=None):
        return linear_rewards(self.features, weights, self.n_states, self.n_actions, _names(names, self.names))

    def point_rewards(self, weights, rows, limit, names=None):
        names = _names(names, self.names)
        return check_reward_scale(self.rewards(weights, rows, names), limit, self.features, weights, names)

    def pull(self, grads, rows=None):
        y = np.asarray(grads).reshape(len(grads), self.n_states * self.n_actions)
        return rows_matmul(y, self.features)

    def jacobian_features(self, rows=None):
        return self.features

    def dense(self, rows=None):
        n = 1 if rows is None else np.asarray(rows).size
        return [np.asarray(self.jacobian_features())] * n

    def digest(self):
        if self._digest is None:
            self._digest = matrix_digest(self.features)
        return self._digest

    def compose(self, dictionary):
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported where the rewards are formed
            F = self.features @ dictionary
        return SharedBasis._product(F, self.n_states, self.n_actions, DICTIONARY_NAMES)

    def factorial_rewards(self, dictionary, coefficients):
        with np.errstate(over="ignore", invalid="ignore"):
            F = self.features @ dictionary
        if not np.all(np.isfinite(F)):  # a StateBroadcast only repeats D: a feature matrix overflowed
            raise ValidationError(
                f"the product features @ dictionary overflows float64: the largest |feature| is "
                f"{np.max(np.abs(self.features)):.3g} and the largest |dictionary entry| {np.max(np.abs(dictionary)):.3g}; "
                "rescale the features (e.g. to entries of order 1)")
        return linear_rewards(F, coefficients, self.n_states, self.n_actions, DICTIONARY_NAMES)

    def dictionary_rewards(self, dictionary, coefficients):
        return linear_rewards(self.features @ dictionary, coefficients, self.n_states, self.n_actions, DICTIONARY_NAMES)

    def check_dictionary_rewards(self, rewards, dictionary, coefficients, limit):
        return check_reward_scale(rewards, limit, self.features @ dictionary, coefficients, DICTIONARY_NAMES)

    def dictionary_gradient(self, grads, coefficients):
        H = np.asarray(coefficients, dtype=np.float64)
        return self.features.T @ (grads.reshape(H.shape[0], self.n_states * self.n_actions).T @ H)

    def factorial_gradients(self, grads, dictionary, coefficients):
        Y = grads.reshape(coefficients.shape[0], -1)
        return Y @ (self.features @ dictionary), self.features.T @ (Y.T @ coefficients)

    def point_pull(self, grads):
        return grads.reshape(len(grads), -1) @ self.features

    def least_squares_weights(self, rewards: NDArray[np.float64]) -> NDArray[np.float64]:
        """Minimum-norm least-squares weights ``W`` (p, m) with ``Phi W ~ X`` for rewards X (S*A, m)."""
        return least_squares_weights(self.features, rewards)

    def start_points(self, weights):
        return self.rewards(weights, names=WEIGHT_NAMES).reshape(len(weights), -1)

    def start_points_from_rewards(self, rewards, n_tasks):
        X = _flat_reward_rows(rewards, n_tasks, self.n_states, self.n_actions)
        return (self.features @ self.least_squares_weights(X.T)).T  # the rewards the least-squares weights give

    def start_dictionary(self, points, n_components, rng, pca):
        D, H = pca(points, n_components, rng)
        return self.least_squares_weights(D), H


class StateBasis(SharedBasis):
    """Rewards of the states only, ``R(s, a) = w(s)``: ``Phi = kron(I_S, 1_A)`` (S*A, S), never formed
    (a :class:`~factirl_opt.tasks.features.StateBroadcast`; p = S, docs/maths.md §7)."""

    def __init__(self, n_states: int, n_actions: int) -> None:
        super().__init__(StateBroadcast(n_states, n_actions), n_states, n_actions)

    def jacobian_features(self, rows=None):
        return self.features.toarray()

    def digest(self):
        return None



def _same_bits(kept: NDArray[np.float64], x: Any) -> bool:
    """Whether ``x`` is a float64 array of ``kept``'s shape and bits (a signed zero or a NaN's
    payload counts: a product of the same bits is the same bits)."""
    return (isinstance(x, np.ndarray) and x.dtype == np.float64 and x.shape == kept.shape
            and np.array_equal(kept.view(np.int64), np.ascontiguousarray(x).view(np.int64)))


class TaskBasis(RewardBasis):
    """One feature matrix per task, ``R_i = Phi_i w_i`` on task i's own environment (docs/maths.md §7).

    Parameters
    ----------
    features : TaskFeatures
        Validated against each task's environment.
    digest : str, optional
        What a model records (one shared matrix given for every environment); default None.

    Notes
    -----
    The per-task products ``Phi_i D`` of the last dictionary (:meth:`compose`,
    :meth:`factorial_rewards`) and ``Phi_i^T y_i`` of the last gradients
    (:meth:`factorial_gradients`) are kept and served again for an equal dictionary or equal
    gradients (the same arrays, so the same bits): the joint scheme evaluates every outer
    iteration's point twice (its step solver's start and the outer loop's check), the second
    time from the objective's cache, and the products cost more than that cache's lookup
    (``Phi_i D`` is 30 x (1024 x 217) @ (217 x 5) on ``bench mce``'s draw). Not pickled.
    """

    shared = False

    def __init__(self, features: TaskFeatures, digest: str | None = None) -> None:
        self.features = features
        self.n_params, self.n_actions = features.n_features, features.n_actions
        self._digest = digest
        self._last_times: tuple[NDArray[np.float64], TaskFeatures] | None = None
        self._last_pull: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        return dict(self.__dict__, _last_times=None, _last_pull=None)

    def _times(self, dictionary: NDArray[np.float64]) -> TaskFeatures:
        """``Phi_i D`` of every task (:meth:`TaskFeatures.times`), the last dictionary's kept."""
        last = self._last_times
        if last is not None and _same_bits(last[0], dictionary):
            return last[1]
        product = self.features.times(dictionary)
        self._last_times = (np.array(dictionary, dtype=np.float64), product)
        return product

    def _pull_all(self, grads: Any) -> NDArray[np.float64]:
        """``Phi_i^T y_i`` (n, p) of every task's gradients (:meth:`pull`), the last stacked ones' kept."""
        if not isinstance(grads, np.ndarray):
            return self.features.pull(grads)
        last = self._last_pull
        if last is not None and _same_bits(last[0], grads):
            return last[1].copy()
        G = self.features.pull(grads)
        self._last_pull = (np.array(grads, dtype=np.float64), G.copy())
        return G

    def check_environments(self, n_states, n_actions):
        S = np.asarray(n_states).reshape(-1)
        if n_actions != self.n_actions or S.size != self.n_tasks or np.any(S != self.features.n_states):
            raise ValidationError(f"the per-task features fit {self.n_tasks} environments of S = "
                                  f"{self.features.n_states.tolist()} states and A = {self.n_actions} actions; got "
                                  f"{S.tolist()} and A = {n_actions}")

    @property
    def n_tasks(self) -> int:
        return self.features.n_tasks

    def rewards(self, weights, rows=None, names=None):
        return self.features.rewards(weights, rows)

    def point_rewards(self, weights, rows, limit, names=None):
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported, naming the inputs
            R = self.features.rewards(weights, rows)
        return check_reward_scale(R, limit, self.features, weights, WEIGHT_NAMES)

    def pull(self, grads, rows=None):
        return self.features.pull(grads, rows)

    def jacobian_features(self, rows=None):
        return self.features.dense(rows)

    def dense(self, rows=None):
        return self.features.dense(rows)

    def subset(self, rows):
        return TaskBasis(self.features.take(rows), self._digest)

    def digest(self):
        return self._digest

    def compose(self, dictionary):
        return TaskBasis(self._times(dictionary))

    def factorial_rewards(self, dictionary, coefficients):
        return self._times(dictionary).rewards(coefficients)

    def dictionary_rewards(self, dictionary, coefficients):
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported by the check
            return self.features.rewards(coefficients @ dictionary.T)

    def check_dictionary_rewards(self, rewards, dictionary, coefficients, limit):
        return check_reward_scale(rewards, limit, self.features, coefficients @ dictionary.T,
                                  ("features", "dictionary @ coefficients"))

    def dictionary_gradient(self, grads, coefficients):
        return self.features.pull(grads).T @ coefficients

    def factorial_gradients(self, grads, dictionary, coefficients):
        G = self._pull_all(grads)  # Phi_i^T y_i (n, p)
        return G @ dictionary, G.T @ coefficients

    def point_pull(self, grads):
        return self.features.pull(grads)

    def start_points(self, weights):
        return weights

    def start_points_from_rewards(self, rewards, n_tasks):
        tf = self.features
        if len(rewards) != tf.n_tasks:
            raise ValidationError(f"flat_rewards must hold one (S_i, A) array per task ({tf.n_tasks}); got {len(rewards)}")
        out = np.empty((tf.n_tasks, tf.n_features))
        for i, (F, R) in enumerate(zip(tf.dense(), rewards)):
            R = check_array(R, f"flat_rewards[{i}] (task {i})")
            shape = (int(tf.n_states[i]), tf.n_actions)
            if R.shape != shape:
                raise ValidationError(f"flat_rewards of task {i} must have shape (S_i, A) = {shape} (its MDP); got {R.shape}")
            out[i] = np.linalg.lstsq(F, R.reshape(-1), rcond=None)[0]
        return out

    def start_dictionary(self, points, n_components, rng, pca):
        """The PCA of the weights in the metric ``G = mean_i Phi_i^T Phi_i`` (state features counted
        once per action): the uncentred PCA of ``W G^{1/2}`` mapped back by the minimum-norm
        pre-image, so ``G^{1/2} D`` has orthonormal columns and ``H = W G D``; the shared start,
        up to the signs of the primitives, when every task has the same features."""
        W = check_array(points, "weights", ndim=2)
        return _metric_pca(W, self.gram(W.shape[0]), n_components, rng, pca)

    def gram(self, n_tasks):
        tf = self.features
        G = np.zeros((tf.n_features, tf.n_features))
        for i in range(tf.n_tasks):
            F = tf.matrix(i)
            G += (tf.n_actions if tf.state_features[i] else 1) * (F.T @ F)
        return G / tf.n_tasks


def least_squares_weights(features: Any, rewards: NDArray[np.float64]) -> NDArray[np.float64]:
    """Minimum-norm least-squares weights ``W`` with ``Phi W ~ X``: rewards mapped back to feature space.

    Parameters
    ----------
    features : ndarray, shape (S*A, p), or StateBroadcast
        ``Phi``. For a :class:`~factirl_opt.tasks.features.StateBroadcast` the solution is the
        mean over the actions.
    rewards : ndarray, shape (S*A, m)
        ``X``, one column per reward.

    Returns
    -------
    ndarray, shape (p, m)
    """
    if isinstance(features, StateBroadcast):
        return (features.T @ rewards) / features.n_actions
    return np.linalg.lstsq(features, rewards, rcond=None)[0]


def as_basis(features: Any, n_states: int | None = None, n_actions: int | None = None) -> RewardBasis:
    """The :class:`RewardBasis` of validated features: a basis as is, None (tabular), a
    :class:`StateBroadcast`, a :class:`TaskFeatures` or one (S*A, p) matrix (``n_states`` and
    ``n_actions`` are then needed)."""
    if isinstance(features, RewardBasis):
        return check_basis(features)
    if isinstance(features, TaskFeatures):
        return TaskBasis(features)
    if n_states is None or n_actions is None:
        raise ValidationError("the features of a shared basis need the MDP's numbers of states and actions")
    if features is None:
        return TabularBasis(n_states, n_actions)
    if isinstance(features, StateBroadcast):
        return StateBasis(n_states, n_actions)
    return SharedBasis(features, n_states, n_actions)


def features_matrix(features: Any, n_states: int, n_actions: int, rows: ArrayLike | None = None) -> Any:
    """The dense features a Jacobian or Hessian in weights is taken along, from features in any form.

    None (tabular): the identity (S*A, S*A); a :class:`StateBroadcast`: formed (S*A, S); a
    :class:`RewardBasis`: its :meth:`~RewardBasis.jacobian_features` of ``rows`` (one matrix, or
    one per row); anything else (an (S*A, p) or (r, S*A, p) array, a list of per-row matrices) as
    given, for the caller to validate.
    """
    if isinstance(features, RewardBasis):
        return features.jacobian_features(rows)
    if features is None or isinstance(features, StateBroadcast):
        return as_basis(features, n_states, n_actions).jacobian_features(rows)
    return features
