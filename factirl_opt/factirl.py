"""FactIRL, the factorial learner (paper section 3.2): a shared dictionary of primitive rewards.

Every task's reward is ``theta_i = D h_i`` (D: (d, k), H: (n, k), tasks on the leading axis).
``fit`` minimises ``J_Xi(D, H) = sum_i J_i(D h_i)`` (eq. 10) by alternating a fixed number of
steps on H with D fixed (the H-step, gradient eq. 12; any registered step solver) and on D
with H fixed (the D-step, gradient eq. 11; Armijo descent). ``transfer`` fits the coefficients
of new tasks with the dictionary fixed (section 4.2).
"""

import numpy as np

import solvers

from ._threads import blas_limited
from ._validation import as_rng, check_beta, check_features, check_int, check_mdp, check_tol
from .demonstrations import empirical_statistics
from .exceptions import NotFittedError, ValidationError
from .gradirl import GradIRL
from .objective import PolicyMatchingObjective
from .problems import dictionary_problem, weights_problem

__all__ = ["FactIRL", "pca_dictionary"]

INITS = ("pca", "random")

#: standard deviation of the coefficients of the "random" initialisation (unit-norm primitives)
RANDOM_INIT_SCALE = 0.3


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
    X = np.asarray(parameters, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] == 0:
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
        rewards (:func:`pca_dictionary`), as the paper recommends. ``"random"``: Gaussian
        primitives normalised to unit norm and ``H ~ N(0, 0.3^2)``, so the initial rewards are
        small (RMS ~0.03 on the 10x10 grid) and the Boltzmann policies start far from
        saturation, where the gradients are informative (a unit-scale random start saturates
        them and the descent stalls). A tuple gives the initial arrays D0 (d, k) and H0 (n, k).
    max_iter : int, default=100
        Maximum outer iterations (one H-step and one D-step each).
    inner_steps : int, default=5
        Fixed number of solver steps per sub-problem.
    tol : float, default=1e-5
        Stop when the relative decrease of the total loss over an outer iteration is below tol.
    h_solver : str or solvers.StepSolver, default="armijo"
        H-step solver (any name of ``solvers.available_solvers()``, e.g. ``"gn-qp-osqp"``);
        ``transfer`` uses it too. A constrained solver keeps its constraint in the
        initialisation and in transfer: for a nonnegative one the primitives of a "pca"
        initialisation are sign-flipped so their coefficients sum to >= 0 (a "random" one
        uses ``|H|``), then H0 is projected; a sparse one's L1 penalty is part of the H
        objective and of ``loss_history_``. The D-step is always Armijo descent.
    h_solver_options : dict, optional
        Options for an ``h_solver`` given by name.
    flat_max_iter : int, default=100
        Iterations of the flat learner used by ``init="pca"``.
    transfer_max_iter : int, default=100
        Maximum solver steps in ``transfer``.
    rng : numpy.random.Generator or int or None
        Randomness of the "random" initialisation (and of completing a rank-deficient PCA).

    Attributes
    ----------
    dictionary_ : ndarray, shape (S*A, k)
    coefficients_ : ndarray, shape (n, k)
    rewards_ : ndarray, shape (n, S, A)
        ``D h_i`` reshaped.
    loss_ : ndarray, shape (n,)
    loss_history_ : list of float
        Total loss (eq. 10) after the initialisation and after each outer iteration.
    n_evaluations_ : int
        Batched Q* evaluations used by ``fit`` (including the flat learner of the PCA init).
    n_iter_ : int
    transfer_loss_history_, transfer_n_evaluations_, transfer_status_
        The same records for the last ``transfer`` call (``transfer_loss_`` is the eq. (5)
        loss per new task, without a solver's penalty; the history includes it, as
        ``loss_history_`` does).
    """

    def __init__(
        self,
        n_primitives=5,
        beta=5.0,
        init="pca",
        max_iter=100,
        inner_steps=5,
        tol=1e-5,
        h_solver="armijo",
        h_solver_options=None,
        flat_max_iter=100,
        transfer_max_iter=100,
        rng=None,
    ):
        self.n_primitives = n_primitives
        self.beta = beta
        self.init = init
        self.max_iter = max_iter
        self.inner_steps = inner_steps
        self.tol = tol
        self.h_solver = h_solver
        self.h_solver_options = h_solver_options
        self.flat_max_iter = flat_max_iter
        self.transfer_max_iter = transfer_max_iter
        self.rng = rng

    def _solver(self):
        return solvers.resolve_solver(self.h_solver, **(self.h_solver_options or {}))

    def _initial(self, mdp, demos_per_task, n, flat_rewards, rng):
        k, d = self.n_primitives, mdp.n_params
        if isinstance(self.init, tuple):
            if len(self.init) != 2:
                raise ValidationError("init given as a tuple must be (D0, H0)")
            D0 = check_features(self.init[0], mdp.n_params, name="init D0")
            H0 = np.asarray(self.init[1], dtype=np.float64)
            if D0.shape != (d, k) or H0.shape != (n, k):
                raise ValidationError(f"init (D0, H0) must have shapes ({d}, {k}) and ({n}, {k}); got {D0.shape} and {H0.shape}")
            return D0.copy(), H0.copy(), 0
        if self.init == "random":
            D0 = rng.standard_normal((d, k))
            D0 /= np.linalg.norm(D0, axis=0)
            return D0, RANDOM_INIT_SCALE * rng.standard_normal((n, k)), 0
        if self.init == "pca":
            evals = 0
            if flat_rewards is None:
                flat = GradIRL(beta=self.beta, max_iter=self.flat_max_iter).fit(mdp, demos_per_task)
                flat_rewards, evals = flat.rewards_, flat.n_evaluations_
            Theta = np.asarray(flat_rewards, dtype=np.float64)
            if Theta.shape != (n, mdp.n_states, mdp.n_actions):
                raise ValidationError(
                    f"flat_rewards must have shape (n, S, A) = ({n}, {mdp.n_states}, {mdp.n_actions}); got {Theta.shape}"
                )
            D, H = pca_dictionary(Theta.reshape(n, d), k, rng)
            return D, H, evals
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
            ``init="pca"`` they are used instead of fitting the flat learner again.

        Returns
        -------
        self
        """
        check_mdp(mdp)
        beta = check_beta(self.beta)
        check_int(self.n_primitives, "n_primitives", minimum=1)
        if self.n_primitives > mdp.n_params:
            raise ValidationError(f"n_primitives={self.n_primitives} exceeds S*A={mdp.n_params}")
        for name in ("max_iter", "inner_steps", "flat_max_iter"):
            check_int(getattr(self, name), name, minimum=1 if name == "inner_steps" else 0)
        check_tol(self.tol)
        h_solver = self._solver().for_alternating()  # the H-step is one block of an alternating scheme
        rng = as_rng(self.rng)
        mu, pi_hat = empirical_statistics(mdp, demos_per_task)
        n = mu.shape[0]
        D, H, init_evals = self._initial(mdp, demos_per_task, n, flat_rewards, rng)
        if getattr(h_solver, "constraint", "none") == "nonneg" and not isinstance(self.init, tuple):
            D, H = _orient_nonneg(D, H, self.init == "random")
        H = h_solver.project(H)
        objective = PolicyMatchingObjective(mdp, mu, pi_hat, beta)
        d_solver = solvers.ArmijoSolver()
        h_state = d_state = None
        S, A = mdp.n_states, mdp.n_actions
        D, H = self._normalise(D, H)
        loss = objective.evaluate((H @ D.T).reshape(n, S, A)).loss
        history = [float(loss.sum() + h_solver.penalty(H).sum())]
        it = 0
        for it in range(1, int(self.max_iter) + 1):
            rh = h_solver.run(weights_problem(objective, D), H, int(self.inner_steps), state=h_state)
            H, h_state = rh.coefficients, rh.state
            rd = d_solver.run(dictionary_problem(objective, H), D.reshape(1, -1), int(self.inner_steps), state=d_state)
            D, d_state = rd.coefficients.reshape(mdp.n_params, -1), rd.state
            loss = objective.evaluate((H @ D.T).reshape(n, S, A)).loss  # cached: the D-step's last point
            D, H = self._normalise(D, H)
            history.append(float(loss.sum() + h_solver.penalty(H).sum()))
            if history[-2] - history[-1] <= self.tol * max(abs(history[-2]), np.finfo(float).tiny):
                break
        self.dictionary_ = D
        self.coefficients_ = H
        self.rewards_ = (H @ D.T).reshape(n, S, A)
        self.loss_ = loss
        self.loss_history_ = history
        self.n_evaluations_ = int(objective.n_evaluations + init_evals)
        self.n_iter_ = it
        return self

    @staticmethod
    def _normalise(D, H, band=2.0):
        """Rescale the primitives to unit norm (H rescaled to match) once one leaves a band.

        The model is invariant to ``D -> D diag(c), H -> H diag(1/c)``; keeping the columns
        of D near unit norm keeps penalties on H (sparse H-steps) meaningful and the two
        sub-problems balanced. Rescaling only when a norm leaves ``[1/band, band]`` avoids
        perturbing the product (in floating point) at every iteration.
        """
        norms = np.linalg.norm(D, axis=0)
        if np.all((norms >= 1.0 / band) & (norms <= band)):
            return D, H
        norms[norms == 0] = 1.0
        return D / norms, H * norms

    @blas_limited
    def transfer(self, mdp, demos_per_task, max_iter=None, h_solver=None, h_solver_options=None):
        """Fit the coefficients of new tasks with the dictionary fixed (section 4.2).

        Starts from ``h = 0`` (projected onto the solver's feasible set) and runs the H-step
        solver for up to ``max_iter`` steps.

        Parameters
        ----------
        mdp : TabularMDP
            Must have S*A equal to the dictionary's first dimension.
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
        D = check_features(self.dictionary_, mdp.n_params, name="dictionary_")
        beta = check_beta(self.beta)
        max_iter = self.transfer_max_iter if max_iter is None else max_iter
        check_int(max_iter, "max_iter", minimum=0)
        check_tol(self.tol)
        if h_solver is None:
            if h_solver_options is not None:
                raise ValidationError("h_solver_options given without h_solver")
            h_solver = self._solver()
        else:
            h_solver = solvers.resolve_solver(h_solver, **(h_solver_options or {}))
        mu, pi_hat = empirical_statistics(mdp, demos_per_task)
        objective = PolicyMatchingObjective(mdp, mu, pi_hat, beta)
        problem = weights_problem(objective, D)
        h0 = h_solver.project(np.zeros((problem.n_rows, problem.n_params)))
        res = h_solver.run(problem, h0, int(max_iter), tol=self.tol)
        self.transfer_coefficients_ = res.coefficients
        self.transfer_rewards_ = (res.coefficients @ D.T).reshape(-1, mdp.n_states, mdp.n_actions)
        self.transfer_loss_ = res.loss - h_solver.penalty(res.coefficients)  # eq. (5) only, like loss_
        self.transfer_loss_history_ = res.loss_history
        self.transfer_n_evaluations_ = int(objective.n_evaluations)
        self.transfer_status_ = res.status
        return res.coefficients

    def __repr__(self):
        return (
            f"FactIRL(n_primitives={self.n_primitives}, beta={self.beta}, init={self.init!r}, "
            f"h_solver={self.h_solver!r}, max_iter={self.max_iter}, inner_steps={self.inner_steps})"
        )
