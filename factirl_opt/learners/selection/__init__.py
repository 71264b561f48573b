"""Model selection: how much FactIRL shares, chosen from the training data (``n_primitives="auto"``,
``residual_penalty="auto"``).

- :mod:`~.folds`: the held-out tasks of each fold; :mod:`~.candidates`: the candidate pairs ``(k, lambda)``;
- :mod:`~.scores`: held-out scores of a transferred reward (likelihood, occupancy);
- :mod:`~.rules`: the choice rules over a scored table;
- :mod:`~.results`: ``SearchResult``, the ``cv_results_`` table, its checks and plot;
- :mod:`~.search`: the engine (:func:`search_sharing`, :func:`score_candidates`, :class:`SearchProgress`);
- :mod:`~.evidence`: Minka's evidence for the rank of the flat start, the ``"evidence"`` route's screen;
- :mod:`~.routes`: one small class per route, in one registry :data:`ROUTES` with one default :data:`DEFAULT_ROUTE`;
- :mod:`~.sharing_search`: :class:`SharingSearch`, the search as FactIRL's parameter;
- :mod:`~.auto`: FactIRL's fit with ``"auto"`` values (the search, then the chosen pair's fit).
"""

from .candidates import AUTO, K_CANDIDATES, LAMBDA_CANDIDATES, max_primitives, sharing_candidates
from .folds import N_FOLDS, take_tasks, task_folds, task_mdp, task_subset
from .results import (CV_RESULTS_KEYS, ROW_KEYS, SearchResult, check_cv_results, cv_results, plot_validation,
                      rows_cv_results, score_rows, validation_rows)
from .routes import (DEFAULT_ROUTE, ROUTE_RULES, ROUTE_UNREAD, ROUTES, SCREEN_TRANSFER_MAX_ITER, SHORT_MAX_ITER,
                     EvidenceRoute, FullRoute, PCARoute, RaceRoute, RaceWarmRoute, Route, ShortRoute, get_route,
                     route_rule)
from .rules import DEFAULT_RULE, RULES, SHARE_LEVEL, choose_row
from .scores import DEFAULT_SCORE, N_TRANSFER_DEMOS, SCORES, held_out_nll, held_out_occupancy_gap
from .search import (RACE_MARGIN, WARM_BUDGET, SearchProgress, bisection_midpoints, choose_sharing, fixed_learner,
                     flat_start_rewards, score_candidates, search_sharing)
from .sharing_search import SharingSearch

__all__ = ["SharingSearch", "ROUTES", "DEFAULT_ROUTE", "ROUTE_RULES", "route_rule", "SHORT_MAX_ITER",
           "SCREEN_TRANSFER_MAX_ITER", "cv_results", "validation_rows"]
