"""How much to share, chosen from the training data: ``FactIRL(n_primitives="auto", residual_penalty="auto")``.

The number of primitives k and the residual penalty lambda (:mod:`factirl_opt.objectives.residuals`)
are chosen by a validation that imitates the use of the learner: K-fold over tasks (:mod:`~.folds`),
for each fold and candidate ``(k, lambda)`` (:mod:`~.routes`) a FactIRL fitted on the other folds'
tasks, each held-out task transferred from its first demonstrations and scored on the others
(:mod:`~.scores`); the choice (:mod:`~.rules`) keeps the flat model unless sharing's paired gain is
significant. The engine is :mod:`~.search`, the table :mod:`~.results`, the ``"evidence"`` route's
screen :mod:`~.evidence`, the search as FactIRL's parameter and its auto fit :mod:`~.sharing_search`.
"""

from .folds import N_FOLDS, task_folds
from .results import (CV_RESULTS_KEYS, ROW_KEYS, SearchResult, check_cv_results, cv_results, plot_validation,
                      rows_cv_results, score_rows, validation_rows)
from .routes import (AUTO, DEFAULT_ROUTE, K_CANDIDATES, LAMBDA_CANDIDATES, max_primitives, sharing_candidates, ROUTE_RULES, ROUTE_UNREAD, ROUTES, SCREEN_TRANSFER_MAX_ITER, SHORT_MAX_ITER,
                     EvidenceRoute, FullRoute, PCARoute, RaceRoute, RaceWarmRoute, Route, ShortRoute, get_route,
                     route_rule)
from .rules import DEFAULT_RULE, RULES, SHARE_LEVEL, choose_row
from .scores import (DEFAULT_SCORE, N_TRANSFER_DEMOS, REFERENCE_SCORES, SCORES, held_out_deviation, held_out_nll,
                     held_out_occupancy_gap, needs_reference)
from .search import (RACE_MARGIN, WARM_BUDGET, SearchProgress, bisection_midpoints, choose_sharing, fixed_learner,
                     flat_start_rewards, reference_rewards, score_candidates, search_sharing)
from .sharing_search import SharingSearch

__all__ = ["SharingSearch", "ROUTES", "DEFAULT_ROUTE", "ROUTE_RULES", "route_rule", "SHORT_MAX_ITER",
           "SCREEN_TRANSFER_MAX_ITER", "cv_results", "validation_rows"]
