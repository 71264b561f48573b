"""FactIRL, the factorial learner (paper section 3.2): a shared dictionary of primitive rewards.

Every task's reward is ``R_i = Phi D h_i``: base features ``Phi`` (S*A, p) (the identity for
tabular rewards, p = S*A), dictionary ``D`` (p, k), coefficients ``H`` (n, k), tasks on the
leading axis (DESIGN section 8).

- :func:`fit_factorial` minimises ``J_Xi(D, H) = sum_i J_i(Phi D h_i)`` (eq. 10) from a given
  start by alternating a fixed number of steps on H with D fixed (the H-step, gradient eq. 12)
  and on D with H fixed (the D-step, gradient eq. 11), each with any registered step solver;
- :func:`transfer_coefficients` fits the coefficients of new tasks with the dictionary fixed
  (section 4.2);
- :class:`FactIRL` is the estimator on top: it validates, initialises (PCA of the flat
  learner's parameters, or random) and stores the learnt attributes.
"""

import dataclasses
from typing import ClassVar

import numpy as np

import solvers

from ._progress import fit_progress
from ._threads import blas_limited
from ._validation import as_rng, check_array, check_bool, check_features, check_int, check_mdp, check_tol
from .exceptions import NotFittedError, ValidationError, translate_solver_errors
from .gradirl import GradIRL, check_solver_applies, make_objective, warn_if_stalled
from .mdp import check_signature
from .problems import dictionary_problem, weights_problem
from .synthetic import task_rewards

__all__ = ["FactIRL", "pca_dictionary", "fit_factorial", "transfer_coefficients", "FactorialFit", "TransferFit"]

INITS = ("pca", "random")

#: default gradient-norm tolerance of :func:`fit_factorial` (relative to the start; see its docstring)
GTOL = 1e-4

#: standard deviation of the coefficients of the "random" initialisation (unit-norm primitives)
RANDOM_INIT_SCALE = 0.3

#: most halvings of a PCA start's coefficients tried by ``FactIRL(pca_shrink=True)`` (factor 2**-20)
PCA_MAX_HALVINGS = 20


def pca_dictionary(parameters, n_components, rng=None):
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


def shrink_coefficients(total_loss, coefficients, max_halvings=PCA_MAX_HALVINGS):
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
        ``total_loss(H) -> float``: the objective of eq. (10) at coefficients H (n, k).
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
    """
    H = np.asarray(coefficients, dtype=float)
    best, j, calls = total_loss(H), 0, 1
    while j < max_halvings:
        trial = total_loss(H * 2.0 ** -(j + 1))
        calls += 1
        if not trial < best:
            break
        best, j = trial, j + 1
    return H * 2.0 ** -j, j, calls


def _orient_nonneg(D, H, fold=False):
    """Prepare an initialisation for a nonnegative H-step (the model ``H D^T`` is unchanged).

    The sign of each primitive is arbitrary (``D[:, l] -> -D[:, l]``, ``H[:, l] -> -H[:, l]``);
    flip the primitives whose coefficients sum to a negative value, so that projecting H onto
    ``H >= 0`` keeps most of each primitive's mass instead of zeroing it. With ``fold`` (the
    random initialisation, whose H is a fresh draw) take ``|H|`` instead.
    """
    if fold:
        return D, np.abs(H)
    sign = np.where(H.sum(axis=0) < 0, -1.0, 1.0)
    return D * sign, H * sign




def normalise_dictionary(D, H, band=2.0):
    """Rescale the primitives to unit norm (H rescaled to match) once one leaves a band.

    The model is invariant to ``D -> D diag(c), H -> H diag(1/c)``; keeping the columns of D
    near unit norm keeps the two sub-problems balanced. Rescaling only when a norm leaves
    ``[1/band, band]`` avoids perturbing the product (in floating point) at every iteration;
    ``band=1`` rescales always (a sparse H-step's L1 penalty is only meaningful for primitives
    of fixed norm, so its fits keep ``||D[:, l]|| = 1``).
    """
    norms = np.linalg.norm(D, axis=0)
    if band > 1 and np.all((norms >= 1.0 / band) & (norms <= band)):
        return D, H
    norms[norms == 0] = 1.0
    return D / norms, H * norms


@dataclasses.dataclass
class FactorialFit:
    """Result of :func:`fit_factorial` (the best point seen).

    Attributes
    ----------
    dictionary : ndarray, shape (p, k)
    coefficients : ndarray, shape (n, k)
    loss : ndarray, shape (n,)
        Per-task objective (without a solver's penalty).
    loss_history : list of float
        Total objective (with the H-solver's penalty) at the start and after each outer iteration.
    n_iter : int
    n_evaluations : int
    status : str
        ``"converged"`` (relative decrease below ``tol``, or gradient norm below ``gtol`` times
        the initial one), ``"max_iter"``, or ``"stalled"`` (the first outer iteration changed
        nothing).
    reason : str
        Why the loop stopped, with the values that met the rule.
    gradient_norm : float
        First-order optimality measure of the total objective over ``(H, D)`` at the last point
        (the norm of the gradient; projected or minimum-norm subgradient for H under a
        constrained or penalised H-solver).
    evaluation_history : list of int
        Q* evaluations used so far at the start and after each outer iteration (aligned with
        ``loss_history``: plot one against the other).
    """

    dictionary: np.ndarray
    coefficients: np.ndarray
    loss: np.ndarray
    loss_history: list
    n_iter: int
    n_evaluations: int
    status: str
    reason: str = ""
    gradient_norm: float = float("nan")
    evaluation_history: list = dataclasses.field(default_factory=list)


def _rewards(mdp, Phi, D, H):
    return task_rewards(D if Phi is None else Phi @ D, H, mdp.n_states, mdp.n_actions)


def _optimality(y, Phi, D, H, h_solver, unit_norm):
    """Norm of the first-order optimality measure of eq. (10) over ``(H, D)``, from ``y = dJ/dR``.

    ``dJ/dh_i = F^T y_i`` with ``F = Phi D`` (eq. 12; projected or minimum-norm subgradient
    for a constrained or penalised H-solver, :meth:`solvers.StepSolver.optimality`) and
    ``dJ/dD = Phi^T sum_i y_i h_i^T`` (eq. 11), restricted to the tangent space of unit-norm
    primitives when the D-step keeps them at unit norm.
    """
    Y = y.reshape(H.shape[0], -1)
    with np.errstate(over="ignore", invalid="ignore"):
        gH = Y @ (D if Phi is None else Phi @ D)
        gD = Y.T @ H if Phi is None else Phi.T @ (Y.T @ H)
        if unit_norm:
            gD = gD - D * np.sum(D * gD, axis=0)
        norm = float(np.hypot(np.linalg.norm(h_solver.optimality(H, gH)), np.linalg.norm(gD)))
    return norm if np.isfinite(norm) else np.inf


def _evaluate_point(objective, Phi, D, H, h_solver, band, unit_norm):
    """Loss per task at ``(D, H)`` (served from the objective's cache after a D-step), the
    normalised pair, the total (with the H-solver's penalty) and the optimality measure."""
    loss, y = objective.loss_and_grad(_rewards(objective.mdp, Phi, D, H))
    D, H = normalise_dictionary(D, H, band)
    total = float(loss.sum() + h_solver.penalty(H).sum())
    return loss, D, H, total, _optimality(y, Phi, D, H, h_solver, unit_norm)


def _outer_stop(history, gnorm, g0, tol, gtol, it):
    """``(status, reason)`` after outer iteration ``it``, or ``(None, None)`` to go on."""
    if it == 1 and history[1] == history[0]:
        return "stalled", "stalled: the first outer iteration changed nothing"  # neither block moved: nothing will
    if solvers.has_converged(history[-2], history[-1], tol):  # a rise is not convergence
        return "converged", f"relative decrease {solvers.relative_decrease(history[-2], history[-1]):.3g} <= tol={tol:g}"
    if solvers.gradient_converged(gnorm, g0, gtol):
        return "converged", f"gradient norm {gnorm:.3g} <= gtol={gtol:g} x initial {g0:.3g}"
    return None, None


def _alternate(objective, Phi, D, H, h_solver, d_solver, max_iter, inner_steps, tol, gtol, report):
    """The alternating loop of eqs. (10)-(12); returns the best point seen, the history and the stop.

    Each block runs ``inner_steps`` steps of its solver's alternating form, warm-started by
    what the solver carries over from its previous run (:meth:`solvers.StepSolver.carry_over`);
    the inner runs stop early only by the gradient rule or a stall (:func:`fit_factorial`).
    """
    penalised = h_solver.constraint == "sparse"
    band = 1.0 if penalised else 2.0
    D, H = normalise_dictionary(D, H, band)  # the H-step starts where the loss is evaluated (no band: no rescaling)
    loss, D, H, total, g0 = _evaluate_point(objective, Phi, D, H, h_solver, np.inf, penalised)
    history, evaluations, gnorm = [total], [objective.n_evaluations], g0
    best = (total, D, H, loss)
    h_state = d_state = None
    status, reason, it = "max_iter", f"max_iter={max_iter} outer iterations done", 0
    for it in range(1, max_iter + 1):
        F = D if Phi is None else Phi @ D
        rh = h_solver.run(weights_problem(objective, F), H, inner_steps, state=h_state, gtol=gtol)
        H, h_state = rh.coefficients, h_solver.carry_over(rh.state)
        rd = d_solver.run(dictionary_problem(objective, H, Phi, unit_norm=penalised), D.reshape(1, -1), inner_steps,
                          state=d_state, gtol=gtol)
        D, d_state = rd.coefficients.reshape(D.shape), d_solver.carry_over(rd.state)
        loss, D, H, total, gnorm = _evaluate_point(objective, Phi, D, H, h_solver, band, penalised)
        history.append(total)
        evaluations.append(objective.n_evaluations)
        report(it, total)
        if total <= best[0]:
            best = (total, D, H, loss)
        stop = _outer_stop(history, gnorm, g0, tol, gtol, it)
        if stop[0] is not None:
            status, reason = stop
            break
    return best, (history, evaluations), it, status, reason, gnorm


@blas_limited
def fit_factorial(mdp, demos_per_task, dictionary, coefficients, *, beta=5.0, base_features=None, h_solver="armijo",
                  h_solver_options=None, d_solver="armijo", d_solver_options=None, max_iter=100, inner_steps=5,
                  tol=1e-5, gtol=GTOL, objective="policy-matching", planner="auto", callback=None, verbose=False):
    """Learn a dictionary and coefficients from a starting point by alternating minimisation.

    Each outer iteration runs up to ``inner_steps`` steps of the H-solver on the coefficients
    (D fixed; eq. 12), then of the D-solver on ``vec(D)`` (H fixed; eq. 11). Returns the best
    point seen, so a fit never ends on a worse point than one it visited.

    Stopping (the rules of :mod:`solvers.stopping`, checked in this order):

    - outer loop, after each outer iteration: ``"stalled"`` when the first one changed
      nothing; ``"converged"`` when the relative decrease of the total objective (eq. 10, plus
      a sparse H-solver's penalty) over the iteration is in ``[0, tol]`` (a rise is not
      convergence), or when the optimality measure over ``(H, D)`` (the norm of the gradient,
      eqs. 11-12; projected or minimum-norm subgradient for a constrained or penalised
      H-solver) is at most ``gtol`` times its value at the start; else ``"max_iter"`` after
      ``max_iter`` iterations. ``reason`` says which rule stopped the fit, with its values.
    - inner runs (each block, each outer iteration): ``inner_steps`` steps, the paper's "fixed
      amount of gradient descent on each sub-problem", ended early only by the gradient rule
      (``gtol``, relative to the run's start) or when the solver stalls (no step decreases the
      block's objective). The relative-decrease rule is not applied inside the loop: stopping
      a block on ``tol`` saved 9% of the Q* evaluations of an Armijo/Armijo fit on a 5x5 grid
      (30 tasks) at the same final loss, but it changes the paper's algorithm, which the
      default (Armijo) fit reproduces unchanged.

    Both solvers are used in their alternating form (``solver.for_alternating()``: the
    Gauss-Newton solvers take proximal, strongly damped steps there), and each run is
    warm-started by what the solver carries over from its previous one
    (``solver.carry_over(state)``: step sizes and damping, but not L-BFGS's curvature pairs,
    which describe the sub-problem before the other block moved).

    Parameters
    ----------
    mdp : TabularMDP
    demos_per_task : list of n task demonstrations
    dictionary : array_like, shape (p, k)
        Initial ``D``; p = S*A (tabular) or the number of base features.
    coefficients : array_like, shape (n, k)
        Initial ``H``.
    beta : float
    base_features : array_like, shape (S*A, p) or (S, p), optional
        ``Phi``; None for tabular rewards.
    h_solver, d_solver : str or solvers.StepSolver
        Step solvers of the two blocks (``solvers.available_solvers()``); the H-solver is used
        in its alternating form (``solver.for_alternating()``).
    h_solver_options, d_solver_options : dict, optional
    max_iter, inner_steps : int
    tol : float
        Relative-decrease tolerance (outer loop and inner runs), >= 0.
    gtol : float, default=GTOL
        Gradient-norm tolerance relative to the start (outer loop and inner runs), >= 0.
        The default stops the long tails of fits whose loss keeps falling geometrically as the
        Boltzmann policies saturate (rewards growing along the fitted directions) and is never
        reached by the paper-scale Armijo/Armijo fit (its gradient stays above 5e-4 x the
        initial one over 100 outer iterations).
    objective : str
        See ``factirl_opt.available_objectives()``.
    planner : str
    callback : callable, optional
        ``callback(iteration, total_objective)`` after each outer iteration.
    verbose : bool
        Progress bar on stderr.

    Returns
    -------
    FactorialFit
    """
    check_mdp(mdp)
    Phi = None if base_features is None else check_features(base_features, mdp.n_params, mdp.n_states)
    p = mdp.n_params if Phi is None else Phi.shape[1]
    D = check_array(dictionary, "dictionary", ndim=2)
    H = check_array(coefficients, "coefficients", ndim=2)
    if D.shape[0] != p or H.shape[1] != D.shape[1]:
        raise ValidationError(f"dictionary (p, k) and coefficients (n, k) must have p = {p} and equal k; got {D.shape} and {H.shape}")
    max_iter, inner_steps = check_int(max_iter, "max_iter", minimum=0), check_int(inner_steps, "inner_steps", minimum=1)
    tol, gtol = check_tol(tol), check_tol(gtol, "gtol")
    obj = make_objective(mdp, demos_per_task, beta, objective, planner)
    if H.shape[0] != obj.n_tasks:
        raise ValidationError(f"coefficients describe {H.shape[0]} tasks but the demonstrations {obj.n_tasks}")
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "FactIRL") as report:
        h = check_solver_applies(solvers.resolve_solver(h_solver, h_solver_options), objective, "h_solver").for_alternating()
        d = check_solver_applies(solvers.resolve_solver(d_solver, d_solver_options), objective, "d_solver").for_alternating()
        best, (history, evaluations), it, status, reason, gnorm = _alternate(obj, Phi, D, h.project(H), h, d, max_iter,
                                                                             inner_steps, tol, gtol, report)
    _, D, H, loss = best
    return FactorialFit(D, H, loss, history, it, int(obj.n_evaluations), status, reason, gnorm, evaluations)


@dataclasses.dataclass
class TransferFit:
    """Result of :func:`transfer_coefficients`.

    Attributes
    ----------
    coefficients : ndarray, shape (n_new, k)
    rewards : ndarray, shape (n_new, S, A)
    loss : ndarray, shape (n_new,)
        Per-task objective, without a solver's penalty.
    loss_history : list of float
        Total objective (with the penalty) at the start and after each step.
    n_iter, n_evaluations : int
    status : str
    """

    coefficients: np.ndarray
    rewards: np.ndarray
    loss: np.ndarray
    loss_history: list
    n_iter: int
    n_evaluations: int
    status: str


@blas_limited
def transfer_coefficients(mdp, demos_per_task, dictionary, *, beta=5.0, base_features=None, h_solver="armijo",
                          h_solver_options=None, max_iter=100, tol=1e-5, objective="policy-matching", planner="auto",
                          callback=None, verbose=False):
    """Coefficients of new tasks with the dictionary fixed (section 4.2).

    Starts from ``h = 0`` (projected onto the solver's feasible set) and runs the H-solver for
    up to ``max_iter`` steps. Parameters as in :func:`fit_factorial`; ``dictionary`` is (p, k).

    Returns
    -------
    TransferFit
    """
    check_mdp(mdp)
    Phi = None if base_features is None else check_features(base_features, mdp.n_params, mdp.n_states)
    D = check_features(dictionary, mdp.n_params if Phi is None else Phi.shape[1], name="dictionary")
    F = D if Phi is None else Phi @ D
    max_iter, tol = check_int(max_iter, "max_iter", minimum=0), check_tol(tol)
    obj = make_objective(mdp, demos_per_task, beta, objective, planner)
    problem = weights_problem(obj, F)
    with translate_solver_errors(), fit_progress(callback, verbose, max_iter, "transfer") as report:
        solver = check_solver_applies(solvers.resolve_solver(h_solver, h_solver_options), objective, "h_solver")
        res = solver.run(problem, solver.project(np.zeros((problem.n_rows, problem.n_params))), max_iter, tol=tol,
                         callback=report)
    rewards = task_rewards(F, res.coefficients, mdp.n_states, mdp.n_actions)
    loss = res.loss - solver.penalty(res.coefficients)
    return TransferFit(res.coefficients, rewards, loss, res.loss_history, res.iterations, int(obj.n_evaluations), res.status)


class FactIRL:
    """Factorial learner: shared dictionary ``D`` and per-task coefficients ``H`` (eqs. 10-12).

    Parameters
    ----------
    n_primitives : int, default=5
        Number of primitive rewards k.
    beta : float, default=5.0
        Boltzmann inverse temperature (eq. 7).
    init : {"pca", "random"} or tuple (D0, H0), default="pca"
        ``"pca"``: learn every task with the flat learner first (``flat_max_iter`` iterations,
        or use ``flat_rewards`` given to ``fit``) and take the uncentred PCA of the learnt
        parameters (:func:`pca_dictionary`), as the paper recommends. With ``features``, of the
        flat learner's feature weights measured by the rewards they give: the PCA of the
        rewards ``Phi w_i`` (the weights' PCA in the metric ``Phi^T Phi``; nested or constant
        features such as Objectworld's leave the weights themselves ill-determined), mapped
        back to feature space by minimum-norm least squares. ``"random"``: Gaussian primitives normalised to unit
        norm and ``H ~ N(0, 0.3^2)``, so the initial rewards are small (RMS ~0.03 on the 10x10
        grid) and the Boltzmann policies start far from saturation, where the gradients are
        informative (a unit-scale random start saturates them and the descent stalls). A tuple
        gives the initial arrays D0 (p, k) and H0 (n, k).
    pca_shrink : bool, default=True
        With ``init="pca"``, halve the start's coefficients while the total loss decreases
        (:func:`shrink_coefficients`; one planning evaluation per trial): the flat learner's
        rewards can be so large that their truncation starts the fit in a saturated region.
        On the paper's grid the policy-matching start is usually kept (two evaluations; halved
        once in 1 of the paper preset's 27 runs), the MCE one halved once; on 32x32
        Objectworld the start shrinks 32-fold. False: the PCA start as it is.
    max_iter : int, default=100
        Maximum outer iterations (one H-step and one D-step each).
    inner_steps : int, default=5
        Fixed number of solver steps per sub-problem.
    tol : float, default=1e-5
        Stop when the relative decrease of the total loss over an outer iteration is below tol
        (a rise is not convergence; the best point seen is kept); see :func:`fit_factorial` for
        both rules and for the inner runs. Transfer stops on ``tol``.
    gtol : float, default=1e-4
        The fit also stops when the gradient norm over (H, D) falls to ``gtol`` times its initial
        value; ``0`` runs the outer iterations to ``tol`` or ``max_iter`` only (the paper's
        fixed budgets, as the ``paper`` preset does).
    h_solver : str or solvers.StepSolver, default="armijo"
        H-step solver (any name of ``solvers.available_solvers()``, e.g. ``"gn-qp-osqp"``);
        ``transfer`` uses it too. A constrained solver keeps its constraint in the
        initialisation and in transfer: for a nonnegative one the primitives of a "pca"
        initialisation are sign-flipped so their coefficients sum to >= 0 (a "random" one
        uses ``|H|``), then H0 is projected; a sparse one's L1 penalty is part of the H
        objective and of ``loss_history_``, and its fits keep unit-norm primitives.
    h_solver_options : dict, optional
        Options for an ``h_solver`` given by name.
    d_solver : str or solvers.StepSolver, default="armijo"
        D-step solver (same registry; ``"armijo"`` is the paper's).
    d_solver_options : dict, optional
    features : array_like, shape (S*A, p) or (S, p), optional
        Base features ``Phi``: rewards ``R_i = Phi D h_i`` with ``D`` of shape (p, k), p >= k
        (state features are repeated over actions). None: tabular, p = S*A.
    objective : str, default="policy-matching"
        Per-task loss (``factirl_opt.available_objectives()``).
    planner : str, default="auto"
        Planning engine (``factirl_opt.available_planners()``).
    flat_max_iter : int, default=100
        Iterations of the flat learner used by ``init="pca"``.
    transfer_max_iter : int, default=100
        Maximum solver steps in ``transfer``.
    rng : numpy.random.Generator or int or None
        Randomness of the "random" initialisation (and of completing a rank-deficient PCA).
    verbose : bool, default=False
        Progress bars on stderr.
    callback : callable, optional
        ``callback(iteration, total_loss)`` after each outer iteration of ``fit`` and each step
        of ``transfer``.

    Attributes
    ----------
    dictionary_ : ndarray, shape (p, k)
    coefficients_ : ndarray, shape (n, k)
    rewards_ : ndarray, shape (n, S, A)
        ``Phi D h_i`` reshaped.
    loss_ : ndarray, shape (n,)
    loss_history_ : list of float
        Total loss (eq. 10, plus a sparse solver's penalty) after the initialisation and after
        each outer iteration.
    n_evaluations_ : int
        Batched planning evaluations used by ``fit`` (including the flat learner of the PCA init).
    n_iter_ : int
        Outer iterations of ``fit``.
    status_ : str
        ``"converged"``, ``"max_iter"`` or ``"stalled"`` (with a :class:`ConvergenceWarning`).
    stop_reason_ : str
        Which stopping rule ended ``fit`` and its values (see :func:`fit_factorial`).
    mdp_signature_ : dict
        Signature of the MDP of ``fit``; ``transfer`` refuses another MDP.
    transfer_coefficients_, transfer_rewards_, transfer_loss_, transfer_loss_history_,
    transfer_n_evaluations_, transfer_status_
        The same records for the last ``transfer`` call (``transfer_loss_`` is the loss per new
        task without a solver's penalty; the history includes it, as ``loss_history_`` does).
    """

    #: The learnt attributes and their kinds, from which ``save_model`` derives what to store and
    #: ``load_model`` what to check (factirl_opt.persistence.learnt): a tuple names the axes of a
    #: finite float array (same name, same length; S, A of the MDP, p parameters), a string a kind.
    learnt_attributes: ClassVar[dict[str, tuple[str, ...] | str]] = {
        "dictionary_": ("p", "k"), "coefficients_": ("n", "k"), "rewards_": ("n", "S", "A"), "loss_": ("n",),
        "loss_history_": "history", "n_evaluations_": "count", "n_iter_": "count", "status_": "text",
        "stop_reason_": "text", "mdp_signature_": "mdp-signature", "features_sha256_": "features-digest",
        "transfer_coefficients_": ("n_new", "k"), "transfer_rewards_": ("n_new", "S", "A"), "transfer_loss_": ("n_new",),
        "transfer_loss_history_": "history", "transfer_n_evaluations_": "count", "transfer_status_": "text",
        "transfer_stop_reason_": "text",
    }

    def __init__(self, n_primitives=5, beta=5.0, init="pca", pca_shrink=True, max_iter=100, inner_steps=5, tol=1e-5, gtol=GTOL,
                 h_solver="armijo",
                 h_solver_options=None, d_solver="armijo", d_solver_options=None, features=None,
                 objective="policy-matching", planner="auto", flat_max_iter=100, transfer_max_iter=100, rng=None,
                 verbose=False, callback=None):
        self.n_primitives = n_primitives
        self.beta = beta
        self.init = init
        self.pca_shrink = pca_shrink
        self.max_iter = max_iter
        self.inner_steps = inner_steps
        self.tol = tol
        self.gtol = gtol
        self.h_solver = h_solver
        self.h_solver_options = h_solver_options
        self.d_solver = d_solver
        self.d_solver_options = d_solver_options
        self.features = features
        self.objective = objective
        self.planner = planner
        self.flat_max_iter = flat_max_iter
        self.transfer_max_iter = transfer_max_iter
        self.rng = rng
        self.verbose = verbose
        self.callback = callback

    def _features(self, mdp):
        if self.features is None:
            return None
        return check_features(self.features, mdp.n_params, mdp.n_states, min_columns=self.n_primitives)

    def _pca_init(self, mdp, demos_per_task, n, Phi, flat_rewards, rng, obj):
        evals = 0
        if flat_rewards is None:
            flat = GradIRL(beta=self.beta, features=Phi, max_iter=self.flat_max_iter, objective=self.objective,
                           planner=self.planner).fit(mdp, demos_per_task)
            X, evals = flat.rewards_.reshape(n, -1), flat.n_evaluations_
        else:
            Theta = check_array(flat_rewards, "flat_rewards")
            if Theta.shape != (n, mdp.n_states, mdp.n_actions):
                raise ValidationError(f"flat_rewards must have shape (n, S, A) = ({n}, {mdp.n_states}, {mdp.n_actions}); got {Theta.shape}")
            X = Theta.reshape(n, -1)
            if Phi is not None:  # the rewards the least-squares feature weights give
                X = (Phi @ np.linalg.lstsq(Phi, X.T, rcond=None)[0]).T
        D, H = pca_dictionary(X, self.n_primitives, rng)
        if Phi is not None:
            D = np.linalg.lstsq(Phi, D, rcond=None)[0]
        if self.pca_shrink:
            H, _, calls = shrink_coefficients(lambda Hs: float(np.sum(obj.loss_and_grad(_rewards(mdp, Phi, D, Hs))[0])), H)
            evals += calls
        return D, H, evals

    def _initial(self, mdp, demos_per_task, n, Phi, flat_rewards, rng, obj):
        k, p = self.n_primitives, mdp.n_params if Phi is None else Phi.shape[1]
        if isinstance(self.init, tuple):
            if len(self.init) != 2:
                raise ValidationError("init given as a tuple must be (D0, H0)")
            D0, H0 = check_array(self.init[0], "init D0"), check_array(self.init[1], "init H0")
            if D0.shape != (p, k) or H0.shape != (n, k):
                raise ValidationError(f"init (D0, H0) must have shapes ({p}, {k}) and ({n}, {k}); got {D0.shape} and {H0.shape}")
            return D0.copy(), H0.copy(), 0
        if isinstance(self.init, str) and self.init == "random":
            D0 = rng.standard_normal((p, k))
            D0 /= np.linalg.norm(D0, axis=0)
            return D0, RANDOM_INIT_SCALE * rng.standard_normal((n, k)), 0
        if isinstance(self.init, str) and self.init == "pca":
            return self._pca_init(mdp, demos_per_task, n, Phi, flat_rewards, rng, obj)
        raise ValidationError(f"init must be one of {INITS} or a tuple (D0, H0); got {self.init!r}")

    @blas_limited
    def fit(self, mdp, demos_per_task, flat_rewards=None):
        """Learn the dictionary and the coefficients of every task.

        Parameters
        ----------
        mdp : TabularMDP
        demos_per_task : list of n task demonstrations
            Each an int array (m, L, 2) or a list of (L_j, 2) episodes.
        flat_rewards : array_like, shape (n, S, A), optional
            Rewards already learnt by the flat learner on these demonstrations; with
            ``init="pca"`` they are used instead of fitting the flat learner again (with
            ``features``, their least-squares feature weights are).

        Returns
        -------
        self
        """
        check_mdp(mdp)
        k = check_int(self.n_primitives, "n_primitives", minimum=1)
        Phi = self._features(mdp)
        p = mdp.n_params if Phi is None else Phi.shape[1]
        if k > p:
            raise ValidationError(f"n_primitives={k} exceeds the reward dimension p={p}")
        check_int(self.flat_max_iter, "flat_max_iter", minimum=0)
        check_bool(self.pca_shrink, "pca_shrink")
        with translate_solver_errors():
            h_solver = check_solver_applies(solvers.resolve_solver(self.h_solver, self.h_solver_options), self.objective,
                                            "h_solver")
            check_solver_applies(solvers.resolve_solver(self.d_solver, self.d_solver_options), self.objective, "d_solver")
        obj = make_objective(mdp, demos_per_task, self.beta, self.objective, self.planner)
        n = len(obj.mu)
        D, H, init_evals = self._initial(mdp, demos_per_task, n, Phi, flat_rewards, as_rng(self.rng), obj)
        if h_solver.constraint == "nonneg" and not isinstance(self.init, tuple):
            D, H = _orient_nonneg(D, H, self.init == "random")
        fit = fit_factorial(mdp, demos_per_task, D, H, beta=self.beta, base_features=Phi, h_solver=h_solver,
                            d_solver=self.d_solver, d_solver_options=self.d_solver_options, max_iter=self.max_iter,
                            inner_steps=self.inner_steps, tol=self.tol, gtol=self.gtol, objective=self.objective,
                            planner=self.planner, callback=self.callback, verbose=self.verbose)
        self.dictionary_, self.coefficients_ = fit.dictionary, fit.coefficients
        self.rewards_ = _rewards(mdp, Phi, fit.dictionary, fit.coefficients)
        self.loss_, self.loss_history_ = fit.loss, fit.loss_history
        self.n_evaluations_ = int(fit.n_evaluations + init_evals)
        self.n_iter_, self.status_, self.stop_reason_ = fit.n_iter, fit.status, fit.reason
        self.mdp_signature_ = mdp.signature()
        warn_if_stalled(fit.status, fit.n_iter, "FactIRL.fit")
        return self

    @blas_limited
    def transfer(self, mdp, demos_per_task, max_iter=None, h_solver=None, h_solver_options=None):
        """Fit the coefficients of new tasks with the dictionary fixed (section 4.2).

        Starts from ``h = 0`` (projected onto the solver's feasible set) and runs the H-step
        solver for up to ``max_iter`` steps (:func:`transfer_coefficients`).

        Parameters
        ----------
        mdp : TabularMDP
            The MDP of ``fit`` (checked against ``mdp_signature_`` when the model has one).
        demos_per_task : list of n_new task demonstrations
        max_iter : int, optional
            Default ``transfer_max_iter``.
        h_solver : str or solvers.StepSolver, optional
            Solver for this call only (e.g. fit with ``"armijo"``, transfer with
            ``"gn-qp-clarabel"``); default the model's ``h_solver``.
        h_solver_options : dict, optional
            Options for an ``h_solver`` given by name here.

        Returns
        -------
        coefficients : ndarray, shape (n_new, k)
        """
        if not hasattr(self, "dictionary_"):
            raise NotFittedError("this FactIRL has no dictionary_: call fit first, or set dictionary_ by hand")
        check_mdp(mdp)
        if getattr(self, "mdp_signature_", None) is not None:
            check_signature(self.mdp_signature_, mdp, "this FactIRL model")
        Phi = self._features(mdp)
        D = check_features(self.dictionary_, mdp.n_params if Phi is None else Phi.shape[1], name="dictionary_")
        if D.shape[1] != self.n_primitives:
            raise ValidationError(f"dictionary_ has {D.shape[1]} primitives but n_primitives={self.n_primitives}")
        if h_solver is None:
            if h_solver_options is not None:
                raise ValidationError("h_solver_options given without h_solver")
            h_solver, h_solver_options = self.h_solver, self.h_solver_options
        res = transfer_coefficients(mdp, demos_per_task, D, beta=self.beta, base_features=Phi, h_solver=h_solver,
                                    h_solver_options=h_solver_options,
                                    max_iter=self.transfer_max_iter if max_iter is None else max_iter, tol=self.tol,
                                    objective=self.objective, planner=self.planner, callback=self.callback,
                                    verbose=self.verbose)
        self.transfer_coefficients_, self.transfer_rewards_ = res.coefficients, res.rewards
        self.transfer_loss_, self.transfer_loss_history_ = res.loss, res.loss_history
        self.transfer_n_evaluations_, self.transfer_status_ = res.n_evaluations, res.status
        warn_if_stalled(res.status, res.n_iter, "FactIRL.transfer")
        return res.coefficients

    def __repr__(self):
        return (
            f"FactIRL(n_primitives={self.n_primitives}, beta={self.beta}, init={self.init!r}, "
            f"h_solver={self.h_solver!r}, d_solver={self.d_solver!r}, objective={self.objective!r}, "
            f"max_iter={self.max_iter}, inner_steps={self.inner_steps})"
        )
