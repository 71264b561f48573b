"""Where a fit starts, as one value: the ``start`` parameter of FactIRL and MultiIntentIRL.

:class:`Start` holds FactIRL's (the initial dictionary and coefficients, and the flat fit the
PCA start decomposes), :class:`IntentionStart` MultiIntentIRL's (the initial responsibilities
and the number of restarts). Each is a frozen dataclass of settings whose fields are the
estimator's nested parameters (``set_params(start__init="random")``); an estimator's
``start=None`` is the default value. The values are validated by ``fit``. :func:`factorial_start`
computes FactIRL's start from them: the PCA of the flat learner's weights in the basis' metric
(with ``pca_shrink``, the coefficients shrunk toward the loss), random primitives, or ``(D0, H0)``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._params import ParameterGroup
from .._validation import check_array
from ..exceptions import FitInterrupted, ValidationError
from ..interruption import INTERRUPTED
from .dictionary import check_dictionary_norms, pca_dictionary, shrink_coefficients
from .factorial import FactorialFit
from .fitting import resolve_step_solver, warn_if_stalled
from .gradirl import STOL, fit_weights
from .solver_settings import SolverSettings, step_solver

__all__ = ["Start", "IntentionStart", "FLAT_TOL", "INITS", "RANDOM_INIT_SCALE", "FLAT_SOLVER", "factorial_start", "flat_solver",
           "flat_start", "pca_start"]

#: the tolerance of the flat learner of the PCA start: GradIRL's default
FLAT_TOL = 1e-5


@dataclasses.dataclass(frozen=True, repr=False)
class Start(ParameterGroup):
    """The start of a :class:`~factirl_opt.FactIRL` fit.

    Parameters
    ----------
    init : {"pca", "random"} or tuple (D0, H0), default="pca"
        ``"pca"``: learn every task with the flat learner first (``flat_max_iter`` iterations,
        or use ``flat_rewards`` given to ``fit``) and take the uncentred PCA of the learnt
        parameters (:func:`~factirl_opt.learners.dictionary.pca_dictionary`), as the paper
        recommends. With ``features``, of the flat learner's feature weights measured by the
        rewards they give: the PCA of the rewards ``Phi w_i`` (the weights' PCA in the metric
        ``Phi^T Phi``; nested or constant features such as Objectworld's leave the weights
        themselves ill-determined), mapped back to feature space by minimum-norm least squares.
        With one feature matrix per task, the PCA of the flat weights in the metric
        ``mean_i Phi_i^T Phi_i`` (:func:`~factirl_opt.learners.dictionary.metric_pca_dictionary`).
        ``"random"``: Gaussian primitives normalised to unit norm and ``H ~ N(0, 0.3^2)``, so the
        initial rewards are small and the Boltzmann policies start far from saturation, where
        the gradients are informative. A tuple gives the initial arrays D0 (p, k) and H0 (n, k).
    pca_shrink : bool, default=True
        With ``init="pca"``, halve the start's coefficients while the total loss decreases
        (:func:`~factirl_opt.learners.dictionary.shrink_coefficients`; one planning evaluation
        per trial): the flat learner's rewards can be so large that their truncation starts the
        fit in a saturated region (on 32x32 Objectworld the start shrinks 32-fold). False: the
        PCA start as it is.
    flat_max_iter : int, default=100
        Iterations of the flat learner used by ``init="pca"``, and by ``transfer`` of the flat
        model (``residual_penalty=0``).
    flat_tol : float, default=1e-5
        Tolerance of the ``init="pca"`` start's flat fit: each task stops when the relative
        decrease of its loss over an iteration is at most ``flat_tol`` (>= 0); on Objectworld
        with a map per task 1e-3 took 30% fewer evaluations for the start
        (``results/fit-speed/README.md``). The flat model's ``transfer`` keeps 1e-5.
    flat_stol : float, default=1e-5
        The flat fit's saturation rule: each task also stops when the decrease of its loss over
        an iteration is at most ``flat_stol`` times its decrease since the start
        (:func:`solvers.stopping.has_saturated`; GradIRL's ``stol`` and its default,
        :data:`~factirl_opt.learners.gradirl.STOL`); 0 turns it off (the paper's flat fit,
        :data:`~factirl_opt.learners.factirl.PAPER_SETTINGS`).
    """

    init: Any = "pca"
    pca_shrink: bool = True
    flat_max_iter: int = 100
    flat_tol: float = FLAT_TOL
    flat_stol: float = STOL


@dataclasses.dataclass(frozen=True, repr=False)
class IntentionStart(ParameterGroup):
    """The start of a :class:`~factirl_opt.MultiIntentIRL` fit.

    Parameters
    ----------
    init : {"agreement", "frequencies", "random"} or array_like, default="agreement"
        The initial responsibilities (``factirl_opt.learners.multi_intent_fit.start_responsibilities``),
        or an array of labels (n_episodes,) or responsibilities (n_episodes, K).
    n_init : int, default=1
        EM runs from different starts; the best by log-likelihood is kept.
    """

    init: Any = "agreement"
    n_init: int = 1


INITS = ("pca", "random")

#: standard deviation of the coefficients of the "random" initialisation (unit-norm primitives)
RANDOM_INIT_SCALE = 0.3

#: the flat learner of FactIRL's PCA start when the solver settings name none: Armijo steps, with
#: the saturation rule ``Start.flat_stol`` (GradIRL's default fit). From it the fast outer scheme
#: kept the train deviation of the paper's fit on per-task maps, where an L-BFGS start did not
#: (``results/defaults/README.md``, "The switch")
FLAT_SOLVER = "armijo"


def flat_start(learner: Any, n: int, basis: Any, obj: Any, rng: Any) -> tuple[Any, int, Any]:
    """What the PCA start decomposes (:meth:`~factirl_opt.tasks.basis.RewardBasis.start_points` of
    the flat learner's weights on ``obj``) and its evaluations; the objective is reset after."""
    solver = resolve_step_solver(*flat_solver(learner), learner.objective, "flat_solver")
    start = learner._group("start")
    ev0 = obj.n_evaluations
    try:
        res = fit_weights(obj, basis, solver, start.flat_max_iter, start.flat_tol, what="FactIRL.fit (flat start)",
                          stol=start.flat_stol)
    except FitInterrupted as exc:  # keep the PCA start of the flat fit as far as it got
        D, H = pca_start(learner, basis.start_points(exc.result.coefficients), basis, rng)
        start = FactorialFit(D, H, np.full(n, np.nan), [], 0, int(obj.n_evaluations), INTERRUPTED, INTERRUPTED)
        raise FitInterrupted(start, "FactIRL.fit") from exc.__cause__
    warn_if_stalled(res.status, res.iterations, "GradIRL.fit")
    obj.reset()  # the factorial fit plans from scratch, as on a fresh objective
    return basis.start_points(res.coefficients), obj.n_evaluations - ev0, res.coefficients


def flat_solver(learner: Any) -> tuple[Any, dict | None]:
    """The flat learner's ``(solver, options)``: the solver settings' ``flat_solver``, else :data:`FLAT_SOLVER`."""
    return step_solver(SolverSettings.of(learner.solver), "flat", (FLAT_SOLVER, None))


def pca_start(learner: Any, X: Any, basis: Any, rng: Any) -> tuple[Any, Any]:
    """The PCA start (D, H) of the flat points X in the basis' metric
    (:meth:`~factirl_opt.tasks.basis.RewardBasis.start_dictionary`: the rewards' PCA mapped back
    to feature space; with per-task features,
    :func:`~factirl_opt.learners.dictionary.metric_pca_dictionary`)."""
    return basis.start_dictionary(X, learner.n_primitives, rng, pca_dictionary)


def _pca_init(learner: Any, n: int, basis: Any, flat_rewards: Any, rng: Any, obj: Any, lam: float) -> tuple:
    """The PCA start ``(D, H, evaluations, W)``: ``W`` None, or with ``lam = 0`` (the flat model,
    module :mod:`factirl_opt.learners.factorial`) the flat start's own weights (n, p), from which
    :meth:`FactIRL.fit` starts the residuals ``delta_i = w_i - D h_i``: the fit begins at the flat model's
    optimum instead of refitting it from ``delta = 0``."""
    if flat_rewards is None:
        X, evals, W = flat_start(learner, n, basis, obj, rng)
    else:
        X, evals = basis.start_points_from_rewards(flat_rewards, n), 0
        W = basis.weights_from_rewards(flat_rewards, n) if lam == 0 else None
    try:
        D, H = pca_start(learner, X, basis, rng)
    except KeyboardInterrupt as exc:
        if isinstance(exc, FitInterrupted):
            raise
        # Ctrl-C in the PCA itself: redo it, and keep it as the start (not evaluated)
        D, H = pca_start(learner, X, basis, rng)
        start = FactorialFit(D, H, np.full(n, np.nan), [], 0, int(obj.n_evaluations), INTERRUPTED, INTERRUPTED)
        raise FitInterrupted(start, "FactIRL.fit") from exc
    if learner._group("start").pca_shrink:
        try:
            H, _, calls = shrink_coefficients(lambda Hs: obj.loss_and_grad(basis.factorial_rewards(D, Hs))[0], H)
        except FitInterrupted as exc:
            Hs, _, _, loss = exc.result
            history = [] if loss is None else [float(np.sum(loss))]
            loss = np.full(n, np.nan) if loss is None else loss
            start = FactorialFit(D, Hs, loss, history, 0, int(obj.n_evaluations), INTERRUPTED, INTERRUPTED)
            raise FitInterrupted(start, "FactIRL.fit") from exc.__cause__
        evals += calls
        obj.reset()
    return D, H, evals, W if lam == 0 else None


def factorial_start(learner: Any, n: int, basis: Any, flat_rewards: Any, rng: Any, obj: Any,
                    lam: float = np.inf) -> tuple:
    """``(D0, H0, evaluations, W)``: the start of the fit (``W``, the flat start's weights, None but
    for a PCA start at ``lam = 0``: :func:`_pca_init`)."""
    k, p = learner.n_primitives, basis.n_params
    init = learner._group("start").init
    if isinstance(init, tuple):
        if len(init) != 2:
            raise ValidationError("init given as a tuple must be (D0, H0)")
        D0, H0 = check_array(init[0], "init D0"), check_array(init[1], "init H0")
        if D0.shape != (p, k) or H0.shape != (n, k):
            raise ValidationError(f"init (D0, H0) must have shapes ({p}, {k}) and ({n}, {k}); got {D0.shape} and {H0.shape}")
        check_dictionary_norms(D0, "init D0")
        return D0.copy(), H0.copy(), 0, None
    if isinstance(init, str) and init == "random":
        D0 = rng.standard_normal((p, k))
        D0 /= np.linalg.norm(D0, axis=0)
        return D0, RANDOM_INIT_SCALE * rng.standard_normal((n, k)), 0, None
    if isinstance(init, str) and init == "pca":
        return _pca_init(learner, n, basis, flat_rewards, rng, obj, lam)
    raise ValidationError(f"init must be one of {INITS} or a tuple (D0, H0); got {init!r}")
