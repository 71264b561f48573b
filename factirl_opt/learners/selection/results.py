"""The results of the sharing search: ``SearchResult``, the table ``cv_results_`` and its checks, the
former validation rows, and the plot."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..._deprecation import warn_once
from ...exceptions import ValidationError

__all__ = ["SearchResult", "score_rows", "cv_results", "validation_rows", "rows_cv_results", "check_cv_results",
           "CV_RESULTS_KEYS", "ROW_KEYS", "plot_validation", "validation_attribute"]


@dataclasses.dataclass
class SearchResult:
    """What :func:`search_sharing` found.

    Attributes
    ----------
    n_primitives : int
        The chosen k.
    residual_penalty : float
        The chosen lambda.
    rows : list of dict
        The validation table (``as_tuple()``'s third value), the chosen row marked.
    folds : list of ndarray of int
        The held-out tasks of each fold, in the order scored.
    scores : dict
        ``{(k, lambda): [per-task scores of each fold scored, in the order of folds]}``.
    n_tasks : int
    unscored : dict
        ``{(k, lambda): reason}``: the candidates that could not be fitted on a fold.
    """

    n_primitives: int
    residual_penalty: float
    rows: list
    folds: list
    scores: dict
    n_tasks: int
    unscored: dict = dataclasses.field(default_factory=dict)

    def as_tuple(self) -> tuple[int, float, list[dict]]:
        return self.n_primitives, self.residual_penalty, self.rows



def score_rows(scores: dict, unscored: dict | None = None) -> list[dict]:
    """The validation table of ``{(k, lambda): [per-task scores of each fold]}`` (as
    :func:`score_candidates` returns them), one row per candidate in the dict's order, as
    :func:`choose_row` takes it (a candidate chosen unscored, with no fold: NaN scores).

    ``unscored`` (``{(k, lambda): reason}``, :attr:`SearchProgress.unscored`) adds each reason to
    its candidate's row, and a row of NaN scores after the others for a candidate never scored."""
    unscored = {} if unscored is None else unscored
    pairs = [*scores, *(c for c in unscored if c not in scores)]
    rows = []
    for k, lam in pairs:
        per_fold = scores.get((k, lam), [])
        rows.append({"n_primitives": k, "residual_penalty": lam,
                     "score": float(np.mean(np.concatenate(per_fold))) if per_fold else np.nan,
                     "score_std": float(np.std([np.mean(f) for f in per_fold])) if per_fold else np.nan,
                     "fold_scores": [float(np.mean(f)) for f in per_fold],
                     "task_scores": [float(v) for v in np.concatenate(per_fold)] if per_fold else [], "chosen": False,
                     "unscored_reason": unscored.get((k, lam), "")})
    return rows


def _with_reasons(rows: list[dict], unscored: dict) -> list[dict]:
    """``rows`` (chosen from) with each unscored candidate's reason, and a row after them for each
    candidate never scored (:func:`score_rows`); the chosen row keeps its index."""
    scored = {(r["n_primitives"], r["residual_penalty"]) for r in rows}
    for row in rows:
        row["unscored_reason"] = unscored.get((row["n_primitives"], row["residual_penalty"]), "")
    return rows + score_rows({}, {c: why for c, why in unscored.items() if c not in scored})


def cv_results(result: SearchResult) -> dict[str, Any]:
    """The table of a search, as ``GridSearchCV.cv_results_``: one entry per candidate in every array.

    Keys: ``param_n_primitives`` (int), ``param_residual_penalty`` (float), ``params`` (list of
    dicts), ``mean_test_score`` and ``std_test_score`` (the mean over the held-out tasks scored
    and the spread of the folds' means; lower scores are better), ``rank_test_score`` (1 the
    lowest mean among the candidates scored on the most folds, which alone are chosen from;
    the others after them; the ``"evidence"`` route's confirmed candidates, chosen from when
    there are any, first), ``split<f>_test_score`` (fold f's mean, NaN where the candidate was
    not scored on it: a race prunes), ``task<j>_test_score`` (task j's held-out score, NaN where
    not scored), ``n_splits_scored``, ``chosen`` (bool, exactly one True), ``confirmed`` (bool: the
    candidate's scores are those of full fits, the ``"evidence"`` route's confirmation of k; the
    others' are the screen's) and ``unscored_reason`` (str: why a candidate could not be fitted on
    a fold, and was scored no further; empty for the others).
    """
    rows, folds, n = result.rows, result.folds, result.n_tasks
    m = len(rows)
    out: dict[str, Any] = {
        "param_n_primitives": np.array([r["n_primitives"] for r in rows], dtype=np.int64),
        "param_residual_penalty": np.array([r["residual_penalty"] for r in rows], dtype=np.float64),
        "params": [{"n_primitives": int(r["n_primitives"]), "residual_penalty": float(r["residual_penalty"])} for r in rows],
        "mean_test_score": np.array([r["score"] for r in rows], dtype=np.float64),
        "std_test_score": np.array([r["score_std"] for r in rows], dtype=np.float64),
    }
    splits = np.full((m, len(folds)), np.nan)
    tasks = np.full((m, n), np.nan)
    for i, r in enumerate(rows):
        per_fold = result.scores.get((r["n_primitives"], r["residual_penalty"]), [])
        for f, values in enumerate(per_fold):
            splits[i, f] = float(np.mean(values))
            tasks[i, folds[f]] = values
    n_scored = np.array([len(r["fold_scores"]) for r in rows], dtype=np.int64)
    confirmed = np.array([bool(r.get("confirmed", False)) for r in rows])
    order = np.lexsort((out["mean_test_score"], -n_scored, ~confirmed))
    rank = np.empty(m, dtype=np.int64)
    rank[order] = np.arange(1, m + 1)
    out["rank_test_score"] = rank
    out.update({f"split{f}_test_score": splits[:, f] for f in range(len(folds))})
    out.update({f"task{j}_test_score": tasks[:, j] for j in range(n)})
    out["n_splits_scored"] = n_scored
    out["chosen"] = np.array([bool(r["chosen"]) for r in rows])
    out["confirmed"] = confirmed
    out["unscored_reason"] = np.array([str(r.get("unscored_reason", "")) for r in rows], dtype=np.str_)
    return out


def validation_rows(results: dict[str, Any]) -> list[dict]:
    """The former validation table (``FactIRL.validation_``, deprecated) of a ``cv_results_``:
    one dict per candidate with ``n_primitives``, ``residual_penalty``, ``score``, ``score_std``,
    ``fold_scores`` (the folds scored), ``task_scores`` (the tasks scored, by task index) and ``chosen``."""
    splits = sorted((k for k in results if k.startswith("split") and k.endswith("_test_score")),
                    key=lambda k: int(k[5:-11]))
    tasks = sorted((k for k in results if k.startswith("task") and k.endswith("_test_score")), key=lambda k: int(k[4:-11]))
    rows = []
    for i in range(len(results["param_n_primitives"])):
        folds = [float(results[k][i]) for k in splits if np.isfinite(results[k][i])]
        per_task = [float(results[k][i]) for k in tasks if np.isfinite(results[k][i])]
        rows.append({"n_primitives": int(results["param_n_primitives"][i]),
                     "residual_penalty": float(results["param_residual_penalty"][i]),
                     "score": float(results["mean_test_score"][i]), "score_std": float(results["std_test_score"][i]),
                     "fold_scores": folds, "task_scores": per_task, "chosen": bool(results["chosen"][i])})
    return rows


#: the keys every ``cv_results_`` has (:func:`cv_results`), each an array of one entry per candidate
CV_RESULTS_KEYS = ("param_n_primitives", "param_residual_penalty", "mean_test_score", "std_test_score",
                   "rank_test_score", "n_splits_scored", "chosen")
#: the keys of a row of the former validation table (:func:`validation_rows`)
ROW_KEYS = ("n_primitives", "residual_penalty", "score", "score_std", "fold_scores", "task_scores", "chosen")


def check_cv_results(results: Any, name: str = "cv_results_") -> None:
    """Refuse a ``cv_results_`` that is not a dict of equal-length arrays with :data:`CV_RESULTS_KEYS` (an edited table).

    Raises
    ------
    ValidationError
        Naming ``name`` and the missing key, or the key whose length differs.
    """
    if not isinstance(results, dict):
        raise ValidationError(f"{name} must be a dict of equal-length arrays (one entry per candidate); got {results!r:.80}")
    missing = [key for key in CV_RESULTS_KEYS if key not in results]
    if missing:
        raise ValidationError(f"{name} has no key {missing[0]!r}: a search's results have {list(CV_RESULTS_KEYS)}")
    m = len(results["param_n_primitives"])
    for key, value in results.items():
        if not hasattr(value, "__len__") or len(value) != m:
            raise ValidationError(f"{name}[{key!r}] must have one entry per candidate ({m}); got {value!r:.60}")
    if m == 0 or int(np.sum(np.asarray(results["chosen"], dtype=bool))) != 1:
        raise ValidationError(f"{name}['chosen'] must mark exactly one candidate; {int(np.sum(results['chosen']))} are")


def _validation(model: Any) -> list[dict]:
    """Deprecated: the rows of ``cv_results_`` (:func:`~factirl_opt.learners.selection.results.validation_rows`)."""
    if "cv_results_" not in vars(model):
        raise AttributeError("'FactIRL' object has no attribute 'validation_' (fit with n_primitives='auto' or "
                             "residual_penalty='auto'; the table is cv_results_ now)")
    warn_once("attr:FactIRL.validation_", "FactIRL.validation_ is deprecated: read cv_results_ (a dict of arrays, "
                                          "one entry per candidate; pandas.DataFrame(model.cv_results_))", stacklevel=2)
    return validation_rows(model.cv_results_)


validation_attribute = property(_validation, lambda model, rows: setattr(model, "cv_results_", rows_cv_results(rows)),
                                doc=_validation.__doc__)


def rows_cv_results(rows: Any, name: str = "validation_") -> dict[str, Any]:
    """A ``cv_results_`` of rows of the former validation table (a file of 0.1.0, or a table set by hand).

    ``fold_scores`` fill ``split<f>_test_score`` in order and ``task_scores`` (when present)
    ``task<j>_test_score`` in order (NaN beyond a row's own).

    Raises
    ------
    ValidationError
        Naming ``name``, the row and the missing key.
    """
    if not isinstance(rows, (list, tuple)) or not rows:
        raise ValidationError(f"{name} must be a non-empty list of rows (dicts); got {rows!r:.80}")
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise ValidationError(f"{name}[{i}] must be a dict with keys {list(ROW_KEYS)}; got {row!r:.80}")
        missing = [key for key in ROW_KEYS if key not in row and key != "task_scores"]
        if missing:
            raise ValidationError(f"{name}[{i}] has no key {missing[0]!r}: a row has {list(ROW_KEYS)}")
    n_folds = max(len(r["fold_scores"]) for r in rows)
    n_tasks = max(len(r.get("task_scores", [])) for r in rows)
    splits, tasks = np.full((len(rows), n_folds), np.nan), np.full((len(rows), n_tasks), np.nan)
    for i, r in enumerate(rows):
        splits[i, :len(r["fold_scores"])] = r["fold_scores"]
        tasks[i, :len(r.get("task_scores", []))] = r.get("task_scores", [])
    scored = np.array([len(r["fold_scores"]) for r in rows], dtype=np.int64)
    mean = np.array([r["score"] for r in rows], dtype=np.float64)
    order = np.lexsort((mean, -scored))
    rank = np.empty(len(rows), dtype=np.int64)
    rank[order] = np.arange(1, len(rows) + 1)
    return {"param_n_primitives": np.array([r["n_primitives"] for r in rows], dtype=np.int64),
            "param_residual_penalty": np.array([r["residual_penalty"] for r in rows], dtype=np.float64),
            "params": [{"n_primitives": int(r["n_primitives"]), "residual_penalty": float(r["residual_penalty"])}
                       for r in rows],
            "mean_test_score": mean, "std_test_score": np.array([r["score_std"] for r in rows], dtype=np.float64),
            "rank_test_score": rank, **{f"split{f}_test_score": splits[:, f] for f in range(n_folds)},
            **{f"task{j}_test_score": tasks[:, j] for j in range(n_tasks)}, "n_splits_scored": scored,
            "chosen": np.array([bool(r["chosen"]) for r in rows])}


def plot_validation(model: Any, ax: Any = None) -> Any:
    """Plot ``model.cv_results_``: mean held-out score (error bars: the folds' spread) against
    lambda, one line per k; the chosen candidate circled. Needs matplotlib.

    Returns
    -------
    matplotlib.axes.Axes

    Raises
    ------
    ValidationError
        The model has no ``cv_results_``, or it lacks a key the plot reads or its arrays differ
        in length (an edited table; :func:`check_cv_results`), naming the key.
    """
    if not hasattr(model, "cv_results_"):
        raise ValidationError("this model has no cv_results_: fit it with n_primitives='auto' or residual_penalty='auto'")
    check_cv_results(model.cv_results_)
    rows = validation_rows(model.cv_results_)
    import matplotlib.pyplot as plt

    if ax is None:
        ax = plt.figure().add_subplot()
    finite = [r["residual_penalty"] for r in rows if np.isfinite(r["residual_penalty"]) and r["residual_penalty"] > 0]
    lo = min(finite, default=1e-2) / 10.0
    hi = max(finite, default=1.0) * 10.0

    def x_of(lam):
        return hi if lam == np.inf else lo if lam == 0.0 else lam

    for k in sorted({r["n_primitives"] for r in rows}):
        mine = sorted((r for r in rows if r["n_primitives"] == k), key=lambda r: x_of(r["residual_penalty"]))
        ax.errorbar([x_of(r["residual_penalty"]) for r in mine], [r["score"] for r in mine],
                    yerr=[r["score_std"] for r in mine], marker="o", label=f"k = {k}")
    chosen = [r for r in rows if r["chosen"]]
    for r in chosen:
        ax.plot([x_of(r["residual_penalty"])], [r["score"]], "o", markersize=14, fillstyle="none", color="k")
    ax.set_xscale("log")
    ax.set_xlabel("residual penalty lambda (left end: 0, right end: inf)")
    ax.set_ylabel("held-out score (lower is better)")
    ax.legend()
    return ax
