"""Where a fit starts, as one value: the ``start`` parameter of FactIRL and MultiIntentIRL.

:class:`Start` holds FactIRL's (the initial dictionary and coefficients, and the flat fit the
PCA start decomposes), :class:`IntentionStart` MultiIntentIRL's (the initial responsibilities
and the number of restarts). Each is a frozen dataclass of settings whose fields are the
estimator's nested parameters (``set_params(start__init="random")``); an estimator's
``start=None`` is the default value. The values are validated by ``fit``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from .._params import ParameterGroup

__all__ = ["Start", "IntentionStart", "FLAT_TOL"]

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
    flat_stol : float, default=0.0
        The flat fit's saturation rule: each task also stops when the decrease of its loss over
        an iteration is at most ``flat_stol`` times its decrease since the start
        (:func:`solvers.stopping.has_saturated`, GradIRL's ``stol``); 0 turns it off.
    """

    init: Any = "pca"
    pca_shrink: bool = True
    flat_max_iter: int = 100
    flat_tol: float = FLAT_TOL
    flat_stol: float = 0.0


@dataclasses.dataclass(frozen=True, repr=False)
class IntentionStart(ParameterGroup):
    """The start of a :class:`~factirl_opt.MultiIntentIRL` fit.

    Parameters
    ----------
    init : {"agreement", "frequencies", "random"} or array_like, default="agreement"
        The initial responsibilities (:func:`~factirl_opt.learners.em.initial_responsibilities`),
        or an array of labels (n_episodes,) or responsibilities (n_episodes, K).
    n_init : int, default=1
        EM runs from different starts; the best by log-likelihood is kept.
    """

    init: Any = "agreement"
    n_init: int = 1
