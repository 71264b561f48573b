"""The dictionary's own error in the transfer posterior: dictionaries refitted on resampled training tasks.

The Laplace posterior of a transferred task (:mod:`~factirl_opt.learners.posterior`) is
conditional on the fitted dictionary ``D``: a new task whose true reward lies off the span of
``D`` deviates whatever its coefficients, and that posterior cannot see it. A model fitted with
``FactIRL(posterior=PosteriorSettings(n_dictionaries=B))`` also refits ``B`` dictionaries, each with the fit's
``(k, lambda)`` on a resample of the training tasks (:func:`resampled_tasks`):

- ``"bootstrap"``: ``n`` tasks drawn with replacement from the ``n`` training tasks (the
  bootstrap over tasks; an ensemble in the sense of Lakshminarayanan et al. 2017);
- ``"folds"``: the tasks of all but one of ``B`` folds (:func:`~factirl_opt.learners.selection.folds.task_folds`),
  the training fits of a ``B``-fold validation over tasks, as the sharing search fits them.

Each refit gives a dictionary ``D_b`` and the Gaussian prior ``(m_b, P_b)`` of its own training
coefficients (:func:`~factirl_opt.learners.transfer.coefficient_prior`). A new task's posterior
under each of them (:func:`member_posteriors`) joins its own as ``LaplacePosterior.members``, and
``sample_rewards`` / ``sample_regrets`` draw from the equal-weight mixture over the ``1 + B``
dictionaries (docs/maths.md §10). The dictionaries differ by an invertible ``k x k`` transform
as well as by their error (``D H = (D A)(A^-1 H)``); each member's prior lives in its own
coordinates, and only rewards are mixed, so the transform does not matter.

Cost: ``B`` fits of the model on ``n`` (bootstrap) or ``n (B - 1) / B`` (folds) tasks, the flat
start of the PCA initialisation computed once on every task and indexed; then ``B`` more
posteriors per ``transfer_posterior_``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._params import ParameterGroup
from .._validation import as_rng, check_int
from ..exceptions import ValidationError
from .fitting import learner_tasks
from .selection.folds import task_folds
from .selection.search import fixed_learner, own_flat_start_rewards
from .transfer import coefficient_prior

__all__ = ["PosteriorSettings", "posterior_settings", "RESAMPLINGS", "NOISE_MODELS", "resampled_tasks", "dictionary_ensemble", "tasks_ensemble", "check_posterior_settings",
           "fit_posterior_terms"]

#: how ``PosteriorSettings(resampling=...)`` resamples the training tasks of each refitted dictionary
RESAMPLINGS = ("bootstrap", "folds")
#: ``PosteriorSettings(noise=...)``: the likelihood's multinomial noise level alone, or scaled by each task's misfit
NOISE_MODELS = ("multinomial", "misfit")


@dataclasses.dataclass(frozen=True, repr=False)
class PosteriorSettings(ParameterGroup):
    """What :class:`~factirl_opt.FactIRL`'s ``transfer_posterior_`` includes besides the coefficients' uncertainty.

    The ``posterior`` parameter of FactIRL (nested parameters ``posterior__n_dictionaries``...;
    ``posterior=None`` is ``PosteriorSettings()``, the conditional posterior of docs/maths.md §10).

    Parameters
    ----------
    n_dictionaries : int, default=0
        ``B`` dictionaries refitted in ``fit``, each with the fit's ``(k, lambda)`` on a resample of
        the training tasks (:func:`dictionary_ensemble`), so that ``sample_rewards`` and
        ``sample_regrets`` marginalise over the dictionary's own error as well as the
        coefficients'. It costs ``B`` more fits, and each posterior ``B`` more posteriors. 0: the
        posterior is conditional on ``dictionary_``.
    resampling : {"bootstrap", "folds"}, default="bootstrap"
        Each refitted dictionary's training tasks: ``n`` drawn with replacement (the bootstrap
        over tasks), or all but one of ``B`` folds (the sharing search's kind of fit); drawn from
        the estimator's ``rng``.
    noise : {"multinomial", "misfit"}, default="multinomial"
        The posterior's noise level under policy matching: the multinomial level of the model's
        policy, or that level scaled by each new task's misfit at its MAP relative to the
        training tasks' (``noise_levels_``): a demonstration the dictionary explains worse than
        it explains its training tasks widens its posterior. ``"misfit"`` needs policy matching.
    """

    n_dictionaries: int = 0
    resampling: str = "bootstrap"
    noise: str = "multinomial"


def posterior_settings(model: Any) -> PosteriorSettings:
    """The model's :class:`PosteriorSettings` (the default for a model without the parameter, e.g. one set up by hand)."""
    if getattr(model, "posterior", None) is None:
        return PosteriorSettings()
    return model._group("posterior")


def check_posterior_settings(model: Any) -> tuple[int, str, str]:
    """``(n_dictionaries, resampling, noise)`` of a FactIRL's :class:`PosteriorSettings`, validated.

    Raises
    ------
    ValidationError
        A negative or non-integer count, 1 dictionary with ``"folds"`` (a fold needs 2), an
        unknown resampling or noise model, or ``"misfit"`` under an objective without a noise
        level (MCE).
    """
    settings = posterior_settings(model)
    if not isinstance(settings, PosteriorSettings):
        raise ValidationError(f"posterior must be a PosteriorSettings or None; got {type(settings).__name__}")
    B = check_int(settings.n_dictionaries, "posterior.n_dictionaries", minimum=0)
    how = settings.resampling
    if how not in RESAMPLINGS:
        raise ValidationError(f"posterior.resampling must be one of {', '.join(RESAMPLINGS)}; got {how!r}")
    if how == "folds" and B == 1:
        raise ValidationError("posterior.resampling='folds' needs posterior.n_dictionaries >= 2 (one dictionary per fold "
                              "left out); got 1")
    noise = settings.noise
    if noise not in NOISE_MODELS:
        raise ValidationError(f"posterior.noise must be one of {', '.join(NOISE_MODELS)}; got {noise!r}")
    return B, how, noise


def resampled_tasks(n_tasks: int, n_dictionaries: int, resampling: str = "bootstrap", rng: Any = None) -> list[NDArray[np.intp]]:
    """The training tasks of each refitted dictionary.

    Parameters
    ----------
    n_tasks : int
        ``n``, the training tasks (at least 2).
    n_dictionaries : int
        ``B``.
    resampling : {"bootstrap", "folds"}
        ``n`` indices drawn with replacement per dictionary, or the complement of each of ``B``
        folds of a random permutation (at most ``n`` folds).
    rng : numpy.random.Generator or int or None

    Returns
    -------
    list of B int arrays (sorted for ``"folds"``)
    """
    n = check_int(n_tasks, "n_tasks", minimum=2)
    B = check_int(n_dictionaries, "n_dictionaries", minimum=1)
    gen = as_rng(rng)
    if resampling == "bootstrap":
        return [gen.integers(0, n, n).astype(np.intp) for _ in range(B)]
    if resampling == "folds":
        if B < 2:
            raise ValidationError(f"resampling='folds' needs at least 2 dictionaries; got {B}")
        everything = np.arange(n)
        return [np.setdiff1d(everything, held).astype(np.intp) for held in task_folds(n, B, gen)]
    raise ValidationError(f"resampling must be one of {', '.join(RESAMPLINGS)}; got {resampling!r}")


def dictionary_ensemble(model: Any, mdp: Any, demos_per_task: Any, n_dictionaries: int, resampling: str = "bootstrap", *,
                        rng: Any = None, flat_rewards: Any = None) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                                            NDArray[np.float64]]:
    """Refit ``model``'s ``(k, lambda)`` on resampled training tasks: the dictionaries and their coefficients' priors.

    Parameters
    ----------
    model : FactIRL
        Fitted (``n_primitives_``, ``residual_penalty_``); each refit is its clone with those
        values fixed and no ensemble of its own.
    mdp, demos_per_task
        The training tasks of ``model.fit`` (parsed once into a task set; each refit fits its
        ``subset(rows)``).
    n_dictionaries : int
        ``B``.
    resampling : {"bootstrap", "folds"}
        :func:`resampled_tasks`.
    rng : numpy.random.Generator or int or None
        The resampling's.
    flat_rewards : array_like, optional
        The flat rewards of the PCA start on every task (as ``fit``'s); None: computed once here
        when the start needs them, and indexed per refit.

    Returns
    -------
    dictionaries : ndarray, shape (B, p, k)
    prior_means : ndarray, shape (B, k)
    prior_precisions : ndarray, shape (B, k, k)
    """
    return tasks_ensemble(model, learner_tasks(model, mdp, demos_per_task), n_dictionaries, resampling, rng=rng,
                          flat_rewards=flat_rewards)


def tasks_ensemble(model: Any, tasks: Any, n_dictionaries: int, resampling: str = "bootstrap", *, rng: Any = None,
                   flat_rewards: Any = None) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`dictionary_ensemble` on the task set of the fit (``tasks``, a TaskSet)."""
    subsets = resampled_tasks(tasks.n_tasks, n_dictionaries, resampling, rng)
    start = model._group("start")
    if flat_rewards is None and isinstance(start.init, str) and start.init == "pca":
        flat_rewards = own_flat_start_rewards(model, tasks)
    Ds, means, precisions = [], [], []
    for idx in subsets:
        member = fixed_learner(model, model.n_primitives_, model.residual_penalty_, posterior=None)
        if isinstance(start.init, tuple):  # a given start (D0, H0): the resampled tasks' rows of H0
            member.set_params(start=dataclasses.replace(start, init=(start.init[0], np.asarray(start.init[1])[idx])))
        member._fit_tasks(tasks.subset(idx), flat_rewards=None if flat_rewards is None else [flat_rewards[int(i)] for i in idx])
        m, P = coefficient_prior(member.coefficients_)
        Ds.append(member.dictionary_)
        means.append(m)
        precisions.append(P)
    return np.stack(Ds), np.stack(means), np.stack(precisions)


def fit_posterior_terms(model: Any, tasks: Any, flat_rewards: Any = None) -> Any:
    """After ``FactIRL.fit`` on ``tasks`` (its task set): the dictionary ensemble of ``posterior.n_dictionaries``
    (:func:`tasks_ensemble`, drawn from the model's ``rng``), or none (an earlier fit's removed); returns ``model``.

    The flat model (``residual_penalty_ = 0``) and a model of fewer than 2 tasks have no posterior,
    hence no ensemble."""
    for name in ("dictionary_ensemble_", "ensemble_prior_means_", "ensemble_prior_precisions_"):
        model.__dict__.pop(name, None)
    B, how, _ = check_posterior_settings(model)
    if B == 0 or float(model.residual_penalty_) == 0.0 or tasks.n_tasks < 2:
        return model
    Ds, means, precisions = tasks_ensemble(model, tasks, B, how, rng=model.rng, flat_rewards=flat_rewards)
    model.dictionary_ensemble_, model.ensemble_prior_means_, model.ensemble_prior_precisions_ = Ds, means, precisions
    return model
