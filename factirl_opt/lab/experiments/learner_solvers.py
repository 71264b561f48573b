"""Which solvers a learner row of the experiments takes (:mod:`.learners`).

A GradIRL row takes the preset's ``flat_solver`` (tabular rewards) or ``flat_features_solver``
(rewards on features); a FactIRL row the run's :class:`~factirl_opt.SolverSettings` and the
preset's ``fact_scheme``. A Gauss-Newton solver needs residuals: a row on an objective without
them (``"mce"``) takes :data:`GRADIENT_FALLBACK` instead; a FactIRL whose solvers the joint
scheme does not apply to alternates (:func:`factorial_scheme`). :func:`substitutions` names
every such replacement before the runs start.
"""

from __future__ import annotations

from typing import Any

import solvers

from ...exceptions import ValidationError
from ...learners.factirl import PAPER_SETTINGS
from ...learners.factorial import check_scheme
from ...learners.gradirl import check_solver_applies
from ...learners.selection import DEFAULT_ROUTE, SharingSearch
from ...learners.solver_settings import SolverSettings
from ...learners.start import Start
from ...objectives.sharding import Execution

__all__ = ["DEFAULT_OBJECTIVE", "GRADIENT_FALLBACK", "SOLVER_ROLES", "ALTERNATING", "flat_solver", "flat_features_solver",
           "factorial_solvers", "factorial_scheme", "substitutions", "factorial_options"]

#: the objective of the paper's learners (eq. 5)
DEFAULT_OBJECTIVE = "policy-matching"

#: the solver a learner on an objective without residuals (``"mce"``) takes where the run or
#: preset names a Gauss-Newton one: the quasi-Newton counterpart, which needs only gradients
GRADIENT_FALLBACK = "lbfgs"

#: which solvers a learner row takes: the preset's ``flat_solver`` (GradIRL, tabular), its
#: ``flat_features_solver`` (GradIRL on features), or the run's :class:`SolverSettings` (FactIRL)
SOLVER_ROLES = ("flat", "flat features", "factorial")

#: the paper's outer scheme, which every FactIRL of a run takes where the preset's does not apply
ALTERNATING = "alternating"

#: the paper's D-step and flat-start solvers (:data:`~factirl_opt.learners.factirl.PAPER_SETTINGS`),
#: which a run's FactIRL takes where its settings name none: the presets' committed tables were
#: made with them, when they were FactIRL's defaults
_PAPER_D_SOLVER = PAPER_SETTINGS["solver"].d_solver
_PAPER_FLAT_SOLVER = PAPER_SETTINGS["solver"].flat_solver


def _applies(name: str, options: dict, objective: str) -> bool:
    """Whether the registered solver ``name`` applies to ``objective`` (Gauss-Newton ones need residuals)."""
    try:
        check_solver_applies(solvers.get_solver(name, **options), objective, "solver")
    except ValidationError:
        return False
    return True


def _replaced(what: str, name: str, objective: str) -> str:
    return (f"{what} {name} replaced by {GRADIENT_FALLBACK} (a Gauss-Newton solver needs residuals; the "
            f"{objective!r} objective has none)")


def _flat_solver(preset: Any, features: bool, objective: str) -> tuple[str, str | None]:
    """The preset's GradIRL solver on features or tabular rewards for ``objective``, and a note
    naming the substitution if there is one."""
    name = preset.flat_features_solver if features else preset.flat_solver
    if _applies(name, {}, objective):
        return name, None
    return GRADIENT_FALLBACK, _replaced("solver", name, objective)


def flat_solver(learner: Any, preset: Any) -> tuple[str, str | None]:
    """The step solver of a GradIRL row, and a note naming the substitution if there is one."""
    return _flat_solver(preset, learner.solvers != "flat", learner.objective)


def flat_features_solver(preset: Any, objective: str = DEFAULT_OBJECTIVE) -> str:
    """The solver of the preset's flat fits on features for ``objective`` (its ``flat_features_solver``,
    or :data:`GRADIENT_FALLBACK` where that is a Gauss-Newton solver and ``objective`` has no residuals):
    what a FactIRL's own flat start on features takes to start as the line-up's FactIRL rows do."""
    return _flat_solver(preset, True, objective)[0]


def factorial_solvers(settings: SolverSettings, objective: str = DEFAULT_OBJECTIVE) -> tuple[SolverSettings, list[str]]:
    """The solver settings a FactIRL on ``objective`` takes, and notes naming the substitutions.

    A learner on an objective without residuals (``"mce"``) cannot take a Gauss-Newton solver
    (``gn-qp-*``, ``gn-cg``): each such H- or D-step solver is replaced by
    :data:`GRADIENT_FALLBACK` without options (its table rows keep the run's solver label).
    """
    h, h_opts, d, d_opts, notes = (settings.h_solver, settings.h_solver_options, settings.d_solver,
                                   settings.d_solver_options, [])
    if not _applies(h, settings.h_options, objective):
        notes.append(_replaced("H-step solver", h, objective))
        h, h_opts = GRADIENT_FALLBACK, ""
    if d and not _applies(d, settings.d_options, objective):
        notes.append(_replaced("D-step solver", d, objective))
        d, d_opts = GRADIENT_FALLBACK, ""
    return (SolverSettings(h, h_opts, d, d_opts) if notes else settings), notes


def factorial_scheme(preset: Any, settings: SolverSettings, objective: str = DEFAULT_OBJECTIVE) -> tuple[str, str | None]:
    """The outer scheme a FactIRL on ``objective`` takes (``FactIRL(scheme=...)``), and a note if it is not the preset's.

    The preset's ``fact_scheme``, unless it is ``"joint"`` and the solvers the FactIRL takes
    (:func:`factorial_solvers`) are ones the joint scheme refuses
    (:func:`~factirl_opt.learners.factorial.check_scheme`: a constrained H-step solver, or a
    D-step solver that needs residuals or a Hessian): that FactIRL alternates. Fits of the
    residual model (the adaptive learner's candidates with a finite penalty) alternate inside
    FactIRL whatever its scheme.
    """
    scheme = preset.fact_scheme
    if scheme == ALTERNATING:
        return scheme, None
    used = factorial_solvers(settings, objective)[0]
    try:
        check_scheme(scheme, solvers.get_solver(used.h_solver, **used.h_options),
                     solvers.get_solver(used.d_solver or _PAPER_D_SOLVER, **used.d_options))
    except ValidationError as exc:
        return ALTERNATING, f"scheme {scheme!r} replaced by {ALTERNATING!r} ({exc})"
    return scheme, None


def substitutions(lineup: Any, preset: Any, settings: SolverSettings) -> list[str]:
    """Every solver a row of the line-up takes instead of the one the preset or run names.

    Returns
    -------
    list of str
        One line per substitution, ``"<split>: <learner>: <what> replaced by <solver> (why)"``.
    """
    out = []
    for lr in lineup.learners:
        if lr.solvers == "factorial":
            notes = factorial_solvers(settings, lr.objective)[1]
            if lr.split == "train":  # the scheme is the fit's; a transfer has none
                notes += [note for note in factorial_scheme(preset, settings, lr.objective)[1:] if note]
        else:
            notes = [note for note in flat_solver(lr, preset)[1:] if note]
        out += [f"{lr.split}: {lr.name}: {note}" for note in notes]
    return out


def factorial_options(preset: Any, settings: SolverSettings, objective: str = DEFAULT_OBJECTIVE,
                      adaptive: bool = False, features: bool = False, init: str = "pca") -> dict[str, Any]:
    """Keyword arguments of every FactIRL of a run: the preset's budgets and scheme, the run's solver settings.

    Every setting a preset relies on is pinned, whatever FactIRL's defaults: the preset's
    scheme (:func:`factorial_scheme`), ``inner_steps``, budgets, ``flat_stol`` and
    ``transfer_stol``, and where the run names no D-step or flat-start solver the paper's
    (``"armijo"``, :data:`~factirl_opt.learners.factirl.PAPER_SETTINGS`): a preset builds the
    FactIRL its committed tables were made with. Solvers that do not apply to ``objective`` are
    replaced (:func:`factorial_solvers`). ``adaptive``: the row's learner chooses k and the residual
    penalty by validation (``n_primitives="auto", residual_penalty="auto"``,
    :mod:`factirl_opt.learners.selection`) instead of the preset's k without residuals, and its
    flat model (``residual_penalty=0``) transfers as the line-up's flat learner does: with the
    preset's ``flat_features_solver`` (``features``: the row learns feature weights) or
    ``flat_solver`` (GradIRL's fallback for an objective a Gauss-Newton solver does not apply to).
    ``init``: the start's (:class:`~factirl_opt.Start`).
    """
    # FactIRL's own flat start (fits without the flat row's rewards) stops as the preset's flat fits
    start = dict(init=init, pca_shrink=preset.pca_shrink, flat_max_iter=preset.flat_max_iter, flat_stol=preset.flat_stol)
    kw = dict(n_primitives="auto" if adaptive else preset.n_primitives, beta=preset.beta, max_iter=preset.fact_max_iter,
              gtol=preset.fact_gtol, tol=preset.fact_tol, inner_steps=preset.inner_steps,
              transfer_max_iter=preset.transfer_max_iter, objective=objective, start=Start(**start),
              execution=Execution(planner=preset.planner), transfer_stol=preset.transfer_stol)
    solver_settings = factorial_solvers(settings, objective)[0]
    if adaptive:
        kw["residual_penalty"] = "auto"
        solver_settings = solver_settings.set_params(flat_solver=_flat_solver(preset, features, objective)[0])
        if preset.sharing_route != DEFAULT_ROUTE:  # the default search: FactIRL's own, as before the routes existed
            kw["sharing_search"] = SharingSearch(route=preset.sharing_route)
    if not solver_settings.d_solver:
        solver_settings = solver_settings.set_params(d_solver=_PAPER_D_SOLVER)
    if not solver_settings.flat_solver:
        solver_settings = solver_settings.set_params(flat_solver=_PAPER_FLAT_SOLVER)
    kw["solver"] = solver_settings
    kw["scheme"] = factorial_scheme(preset, settings, objective)[0]
    return kw
