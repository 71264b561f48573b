"""The learners layer: the three estimators and the fitting schemes behind them.

- :class:`GradIRL` (:mod:`~factirl_opt.learners.gradirl`): the flat learner, one reward per task.
- :class:`FactIRL` (:mod:`~factirl_opt.learners.factirl`): the factorial learner; its
  alternating scheme (:mod:`~factirl_opt.learners.factorial`), dictionary steps
  (:mod:`~factirl_opt.learners.dictionary`) and transfer (:mod:`~factirl_opt.learners.transfer`).
- :class:`MultiIntentIRL` (:mod:`~factirl_opt.learners.multi_intent`): EM over unlabeled
  episodes (:mod:`~factirl_opt.learners.em`, :mod:`~factirl_opt.learners.multi_intent_fit`)
  and the choice of the number of intentions (:mod:`~factirl_opt.learners.intention_count`).
- The grouped parameters: :class:`SolverSettings` (the step solvers a learner runs),
  :class:`Execution` (where and how a fit runs and is watched), :class:`Start` and
  :class:`IntentionStart` (where a FactIRL or MultiIntentIRL fit starts; :mod:`~factirl_opt.learners.start`),
  :class:`PosteriorSettings` (what FactIRL's transfer posterior includes; :mod:`~factirl_opt.learners.dictionary_ensemble`),
  :class:`DictionaryConstraint` (a constraint on FactIRL's primitives; :mod:`~factirl_opt.learners.dictionary`).
- :class:`LaplacePosterior` (:mod:`~factirl_opt.learners.posterior`): a transferred task's
  posterior (``FactIRL.transfer_posterior_``); active requests in :mod:`~factirl_opt.learners.active`.
- :func:`importance_posterior` and :class:`ParticlePosterior` (:mod:`~factirl_opt.learners.particle_posterior`):
  the same tasks' posterior without the Gaussian approximation, the prior's draws weighted by the
  demonstrations' likelihood (ranks new tasks by their regret; costs planning the draws).
- :class:`GPIReport` (:mod:`~factirl_opt.learners.gpi`): what ``FactIRL.gpi_policies`` found,
  policies of new tasks by generalised policy improvement over the successor features of a library.
- :class:`SharingSearch` (:mod:`~factirl_opt.learners.selection`): how ``FactIRL``'s ``"auto"``
  values are chosen (the model-selection package: folds, scores, rules, results, routes, the engine).

Learners never know which step solver, objective or planner runs: they take them by name.
"""

from .estimator import clone
from .factirl import PAPER_SETTINGS, FactIRL, fit_factorial, pca_dictionary, transfer_coefficients
from .gpi import GPIReport
from .gradirl import GradIRL
from .multi_intent import MultiIntentIRL, adjusted_rand_index, match_intentions
from .posterior import LaplacePosterior
from .particle_posterior import ParticlePosterior, importance_posterior
from .selection.results import plot_validation
from .selection.sharing_search import SharingSearch
from .solver_settings import SolverSettings
from .start import IntentionStart, Start
from .dictionary_ensemble import PosteriorSettings
from .dictionary import DictionaryConstraint
from ..objectives.sharding import Execution

__all__ = [
    "GradIRL",
    "FactIRL",
    "PAPER_SETTINGS",
    "MultiIntentIRL",
    "SolverSettings",
    "Execution",
    "Start",
    "PosteriorSettings",
    "DictionaryConstraint",
    "IntentionStart",
    "SharingSearch",
    "clone",
    "plot_validation",
    "fit_factorial",
    "transfer_coefficients",
    "pca_dictionary",
    "adjusted_rand_index",
    "match_intentions",
    "LaplacePosterior",
    "ParticlePosterior",
    "importance_posterior",
    "GPIReport",
]
