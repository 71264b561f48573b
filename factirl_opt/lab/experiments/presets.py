"""Experiment presets: the paper's section 4 (and the Objectworld benchmark) as data, run by :mod:`.runner`.

A preset fixes the world (its name in :data:`.worlds.WORLDS`, grid, dynamics, discount), the
ground truth (number of primitives, coefficient distribution), the demonstrations, the learner
line-up (its name in :data:`.learners.LINEUPS`), the planner, the learners' iteration budgets,
the factorial learner's default solvers and the two sweeps of figures 1 and 2:

- demos per task (``demos_sweep``) at ``default_tasks`` training tasks;
- number of training tasks (``tasks_sweep``) at ``default_demos`` demos per task.

The default point ``(default_tasks, default_demos)`` belongs to both sweeps and is run once.
Every point is run for ``n_seeds`` seeds (``--seed BASE`` gives seeds BASE, BASE+1, ...).

Presets
-------
``paper``
    The paper's setting: 10x10 grid, k = 5 primitives, demonstrations of 10 steps, 100
    training tasks with 10 demos each at the default point, sweeps (1, 2, 5, 10, 20) demos and
    (5, 10, 20, 50, 100) tasks, 100 test tasks with one demonstration each, 3 seeds.
``fast``
    The ``paper`` world, sweeps, test tasks and seeds with faster solvers, stopping rules and
    budgets (:data:`FAST_SOLVERS`): FactIRL with Gauss-Newton QP H-steps through Clarabel
    (also in transfer), L-BFGS D-steps, 2 + 2 inner steps per outer iteration, at most 50
    outer iterations, stopping at a gradient norm 1e-3 times the initial one or a relative
    decrease 1e-4; the flat learners with L-BFGS on tabular rewards and Gauss-Newton QP steps
    on features. ``reproduce --preset fast --jobs 2`` is timed in the README next to the
    paper preset, and its results are committed under ``results/fast/``.
``quick``
    Every learner and figure of the paper, the README's first command (its runs took 14 s of wall
    time with ``--jobs 1``, ``results/setup/quick-manifest.json``): an 8x8 grid (the paper's
    dynamics and k = 5 primitives), 3 points (3 and 10 demos at 40 tasks; 5 and 40 tasks at 10
    demos), 15 test tasks, 1 seed, and shorter budgets (GradIRL 50 iterations, FactIRL 30 outer
    iterations, transfer 50 steps); the paper's orderings hold at its default point.
``test``
    The paper's world and learners at one point (50 tasks, 10 demos, 50 test tasks, 1 seed):
    what the regression tests run to check the paper's orderings.
``tiny``
    A 5x5 grid with a handful of tasks and few iterations: seconds, for tests of the machinery
    (resume, ``--jobs`` invariance, command line); its scores mean nothing.
``objectworld``
    ELIRL's multi-task Objectworld (world and line-up ``"objectworld"``): 32x32, c1 = 5 inner
    colours (one true primitive each, k = 5), c2 = 2 outer colours, object density 0.05,
    determinism 0.7, gamma 0.9; 100 training tasks x 32 demonstrations of 16 steps at the
    default point, a sweep over the number of training tasks (10, 20, 50, 100), 100 test
    tasks with one demonstration each, 3 seeds; the ``fast`` preset's solvers and budgets,
    with L-BFGS for the flat fits on features too (:data:`OBJECTWORLD_SOLVERS`), FactIRL's
    joint scheme and GradIRL's saturation rule (``flat_stol = 1e-5``) in every flat fit
    (:data:`OBJECTWORLD_FULL_SOLVERS`; the quick, tiny and sharing Objectworld presets keep
    the alternation and ``flat_stol = 0``).
``objectworld-quick``
    The same at 16x16 (the committed run: 3 min with ``--jobs 1``): 5 and 20 training tasks x 16
    demonstrations, 20 test tasks, 3 seeds, GradIRL 40 iterations, FactIRL 15 outer
    iterations, transfer 40 steps; the regression test's orderings.
``objectworld-tiny``
    An 8x8 Objectworld (object density 0.15), a few tasks and iterations: seconds, the smoke
    test of the Objectworld machinery; its scores mean nothing.
``objectworld-per-task``
    ELIRL's benchmark as its script runs it (world and line-up ``"objectworld-per-task"``):
    every task on its own map (the ``objectworld`` preset's size, colours, density, dynamics,
    demonstrations, sweeps, test tasks, seeds, solvers and budgets), the test tasks on maps
    never seen in training; every learner on feature weights, scored on the tasks' own maps
    (``deviation``) and on fresh maps of the same tasks (``new_maps_deviation``).
``objectworld-per-task-quick``
    The same at 8x8 (object density 0.15) with ``objectworld-quick``'s points, test tasks,
    seeds and budgets: the regression test's orderings.
``babyai`` / ``babyai-large`` / ``babyai-quick``
    BabyAI-GoToLocal-v0 / GoToOpen-v0 (world and line-up ``"babyai"``, :mod:`.babyai`; k = 8,
    :data:`BABYAI_SOLVERS`): 10-30-100 / 10-30 / 12 training layouts x 4 / 2 / 3 bot
    demonstrations, 100 / 30 / 10 test layouts with ONE each, 3 / 1 / 1 seeds; scored by success.
``sharing-grid`` / ``sharing-objectworld-quick`` / ``sharing-objectworld-per-task-quick`` / ``sharing-babyai`` / ``sharing-babyai-large``
    "Which learner when" (:data:`SHARING_PRESETS`; ``factirl-opt bench which-learner`` runs them all): the
    flat learner, the factorial learner with the preset's k and the adaptive learner (k and the
    residual penalty chosen by validation), line-ups ``"sharing"``, ``"objectworld-sharing"``,
    ``"objectworld-per-task-sharing"`` and ``"babyai-sharing"`` (:mod:`.learners`), 3 seeds, in
    the worlds and with the budgets of ``paper`` (at 5, 20 and 100 training tasks x 10 demos),
    ``objectworld-quick``, ``objectworld-per-task-quick``, ``babyai`` (10 and 30 training layouts)
    and ``babyai-large`` (10 training layouts). ``sharing-tiny``: the same on ``tiny`` (seconds).

Any preset runs another line-up (``dataclasses.replace(preset, lineup="paper+mce")``, or
``factirl-opt reproduce --lineup``) or planner; those fields enter the fingerprint only when
they differ from the paper's (:data:`LATER_FIELDS`), so the paper's runs keep their keys.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from typing import Any

import solvers

from ...validation import check_bool, check_int, check_probability, check_real
from ...exceptions import FactIRLError, ValidationError, translate_solver_errors
from ...planning import available_planners
from ...learners.factorial import SCHEMES
from ...learners.selection import DEFAULT_ROUTE
from ...learners.solver_settings import SolverSettings
from ...learners.transfer import TRANSFER_STOL
from ...datasets.synthetic import COEFFICIENT_KINDS

__all__ = ["Preset", "PRESETS", "PRESET_DESCRIPTIONS", "LATER_FIELDS", "SHARING_PRESETS", "get_preset"]

#: fields added after the paper's preset, with their defaults: they enter a preset's fingerprint
#: (and so its runs' keys) only when they differ from these
LATER_FIELDS = {"world": "grid", "lineup": "paper", "planner": "auto", "n_outer_colours": 2, "object_density": 0.05,
                "fact_gtol": 0.0, "fact_tol": 1e-5, "flat_gtol": 0.0, "flat_stol": 0.0, "flat_solver": "armijo", "flat_features_solver": "armijo",
                "pca_shrink": False, "sharing_route": "race", "fact_scheme": "alternating", "transfer_stol": 0.0}
#: the fields of :class:`~factirl_opt.SolverSettings`, flattened into :meth:`Preset.to_dict`: part of
#: each run's key, not of the fingerprint
SOLVER_FIELDS = ("h_solver", "h_solver_options", "d_solver", "d_solver_options")


@dataclasses.dataclass(frozen=True)
class Preset:
    """One experiment configuration (see the module docstring for the presets).

    Parameters
    ----------
    name : str
    grid_size : int
        Side of the grid world.
    p_success : float
        Probability that a feasible move succeeds (Objectworld: the probability of the intended
        move, its ``determinism``).
    gamma : float
        Discount factor.
    beta : float
        Boltzmann inverse temperature of every learner.
    n_primitives : int
        k, the size of the true dictionary and of the learnt ones (Objectworld: also c1, the
        number of inner colours, one true primitive each).
    coefficient_kind : {"gaussian", "nonneg"}
        Distribution of the true mixing coefficients (:func:`factirl_opt.random_coefficients`;
        the grid world only).
    demo_length : int
        Steps per demonstration (train and test).
    demos_sweep : tuple of int
        Demos per training task, swept at ``default_tasks`` tasks.
    tasks_sweep : tuple of int
        Numbers of training tasks, swept at ``default_demos`` demos per task.
    default_tasks, default_demos : int
        The paper's default point; figure 3 shows its first seed.
    n_test_tasks : int
        New tasks (one demonstration each) scored in the transfer experiment.
    n_features_from_examples : int
        Learnt training rewards used as features by ``flat, features from ex.`` (all of them
        when there are fewer training tasks).
    n_pca_components : int
        Components of ``flat, PCA features``.
    flat_max_iter : int
        Iterations of every GradIRL fit (flat learner, with or without features).
    flat_gtol : float
        GradIRL's gradient stopping rule (``GradIRL(gtol=...)``) in every flat fit of the runs:
        0, the committed protocol (each flat fit stops by its tolerance on the loss's decrease or
        at ``flat_max_iter``), where the library's default stops a saturating task by its gradient.
    flat_stol : float
        GradIRL's saturation rule (``GradIRL(stol=...)``) in every flat fit of the runs: 0, the
        committed protocol, where the library's default (1e-5) stops a task once an iteration
        decreases its loss by at most that fraction of its decrease since the start. Also
        FactIRL's own flat start where a fit computes one (``FactIRL(flat_stol=...)``, as in
        ``bench mce``; the line-ups' factorial rows start from the flat row's rewards).
    fact_max_iter : int
        Outer iterations of FactIRL.
    fact_gtol : float
        FactIRL's gradient stopping rule (``FactIRL(gtol=...)``); 0, the paper's fixed budgets,
        except in ``fast``.
    inner_steps : int
        Solver steps per FactIRL sub-problem.
    transfer_max_iter : int
        H-step solver steps of ``FactIRL.transfer``.
    n_seeds : int
        Default number of seeds.
    world : str
        The world's name in :data:`.worlds.WORLDS` (``"grid"``: the paper's).
    lineup : str
        The learner line-up's name in :data:`.learners.LINEUPS` (``"paper"``).
    planner : str
        Planning engine of every learner, of the demonstrations and of the scores (a name in
        :func:`factirl_opt.available_planners`; ``"auto"``: dense up to ``planning.AUTO_DENSE_MAX_STATES`` states, sparse LU
        above).
    n_outer_colours : int
        Objectworld only: c2, the number of outer (distractor) colours.
    object_density : float
        Objectworld only: the probability that a cell holds an object.
    fact_tol : float
        FactIRL's relative-decrease stopping rule (``FactIRL(tol=...)``; 1e-5, its default,
        except in ``fast``).
    pca_shrink : bool
        ``FactIRL(pca_shrink=...)``: shrink the PCA start while the loss decreases. False (the
        paper's PCA start as it is) except in ``fast`` and the Objectworld presets, whose
        flat fits reach large rewards (L-BFGS; near-deterministic demonstrations).
    flat_solver, flat_features_solver : str
        Step solvers of the line-up's GradIRL fits (flat learners, train and test) on tabular
        rewards and on features (names in ``solvers.available_solvers()``, without options):
        ``"armijo"``, the paper's, except in ``fast``. A Gauss-Newton solver is replaced by
        L-BFGS for the learners on an objective without residuals (``"mce"``), like the
        factorial ones' (:data:`.learners.GRADIENT_FALLBACK`).
    sharing_route : str
        The route of the adaptive learner's search (``FactIRL(sharing_search=SharingSearch(route=...))``,
        :data:`factirl_opt.learners.selection.ROUTES`): ``"race"`` (the route the committed tables
        of the presets other than ``sharing-*`` were made with), except on the ``sharing-*``
        presets, which take FactIRL's default route, ``"evidence"``; ``bench which-learner
        --route`` asks for another.
    fact_scheme : {"alternating", "joint"}
        FactIRL's outer scheme (``FactIRL(scheme=...)``, :func:`factirl_opt.learners.factorial.check_scheme`):
        the paper's alternation, except in the full-size Objectworld presets (``objectworld``,
        ``objectworld-per-task``), whose FactIRL rows take ``"joint"`` steps of their L-BFGS
        D-step solver on the dictionary and coefficients together. A FactIRL the joint scheme
        does not apply to (a constrained H-step solver, a D-step solver needing residuals, the
        residual model's fits) alternates (:func:`.learner_solvers.factorial_scheme`).
    transfer_stol : float
        The saturation rule of FactIRL's ``transfer`` (``FactIRL(transfer_stol=...)``): 0, the
        maximum-likelihood transfer the committed tables of the paper's and the other
        reproduction presets were made with, except in the "which learner when" presets
        (:data:`SHARING_PRESETS`), which take FactIRL's default,
        :data:`~factirl_opt.learners.transfer.TRANSFER_STOL`.
    solvers : SolverSettings
        The factorial learner's H-step and D-step solvers when a sweep names none
        (:class:`factirl_opt.SolverSettings`; default: Armijo H-steps and, as no D-step is
        named, the paper's Armijo D-step, pinned by :func:`.learner_solvers.factorial_options`). Not part of the fingerprint: part of every run's key
        (:class:`.runner.RunSpec`), so a ``fast`` run and a ``paper`` run with the same
        ``--h-solver`` and ``--d-solver`` are the same run. :meth:`to_dict` flattens it into
        its four fields (:data:`SOLVER_FIELDS`).
    """

    name: str
    grid_size: int = 10
    p_success: float = 0.7
    gamma: float = 0.9
    beta: float = 5.0
    n_primitives: int = 5
    coefficient_kind: str = "gaussian"
    demo_length: int = 10
    demos_sweep: tuple = (1, 2, 5, 10, 20)
    tasks_sweep: tuple = (5, 10, 20, 50, 100)
    default_tasks: int = 100
    default_demos: int = 10
    n_test_tasks: int = 100
    n_features_from_examples: int = 15
    n_pca_components: int = 5
    flat_max_iter: int = 100
    fact_max_iter: int = 100
    inner_steps: int = 5
    transfer_max_iter: int = 100
    n_seeds: int = 3
    world: str = "grid"
    lineup: str = "paper"
    planner: str = "auto"
    n_outer_colours: int = 2
    object_density: float = 0.05
    fact_gtol: float = 0.0
    fact_tol: float = 1e-5
    flat_gtol: float = 0.0
    flat_stol: float = 0.0
    flat_solver: str = "armijo"
    flat_features_solver: str = "armijo"
    pca_shrink: bool = False
    sharing_route: str = "race"
    fact_scheme: str = "alternating"
    transfer_stol: float = 0.0
    solvers: SolverSettings = SolverSettings()

    def __post_init__(self) -> None:
        where = f"preset {self.name!r}: "
        for f in ("grid_size", "n_primitives", "demo_length", "default_tasks", "default_demos", "n_test_tasks",
                  "n_features_from_examples", "n_pca_components", "flat_max_iter", "fact_max_iter",
                  "inner_steps", "transfer_max_iter", "n_seeds", "n_outer_colours"):
            object.__setattr__(self, f, check_int(getattr(self, f), where + f, minimum=1))
        for f in ("demos_sweep", "tasks_sweep"):
            v = getattr(self, f)
            if not isinstance(v, tuple) or not v:
                raise ValidationError(f"{where}{f} must be a non-empty tuple of integers >= 1; got {v!r}")
            object.__setattr__(self, f, tuple(check_int(x, f"{where}{f}[{i}]", minimum=1) for i, x in enumerate(v)))
        object.__setattr__(self, "p_success", check_probability(self.p_success, where + "p_success"))
        object.__setattr__(self, "object_density", check_real(self.object_density, where + "object_density", 0.0, 1.0,
                                                              low_open=True))
        object.__setattr__(self, "gamma", check_real(self.gamma, where + "gamma", 0.0, 1.0, high_open=True))
        object.__setattr__(self, "fact_gtol", check_real(self.fact_gtol, where + "fact_gtol", low=0.0))
        object.__setattr__(self, "fact_tol", check_real(self.fact_tol, where + "fact_tol", low=0.0))
        object.__setattr__(self, "flat_gtol", check_real(self.flat_gtol, where + "flat_gtol", low=0.0))
        object.__setattr__(self, "flat_stol", check_real(self.flat_stol, where + "flat_stol", low=0.0))
        object.__setattr__(self, "transfer_stol", check_real(self.transfer_stol, where + "transfer_stol", low=0.0))
        object.__setattr__(self, "beta", check_real(self.beta, where + "beta", low=0.0, low_open=True))
        object.__setattr__(self, "pca_shrink", check_bool(self.pca_shrink, where + "pca_shrink"))
        from .learners import LINEUPS
        from .worlds import PER_TASK_WORLDS, WORLDS
        from ...learners.selection import ROUTES

        for f, choices in (("coefficient_kind", COEFFICIENT_KINDS), ("world", WORLDS), ("lineup", LINEUPS),
                           ("planner", available_planners()), ("sharing_route", list(ROUTES)),
                           ("fact_scheme", list(SCHEMES))):
            if getattr(self, f) not in choices:
                raise ValidationError(f"{where}{f} must be one of {', '.join(choices)}; got {getattr(self, f)!r}")
        worlds = LINEUPS[self.lineup].worlds
        if worlds and self.world not in worlds:
            raise ValidationError(f"{where}the line-up {self.lineup!r} runs in the world(s) {', '.join(worlds)}; "
                                  f"got world {self.world!r}")
        if LINEUPS[self.lineup].one_mdp and self.world in PER_TASK_WORLDS:
            raise ValidationError(f"{where}the line-up {self.lineup!r} plans every task on one MDP; the world "
                                  f"{self.world!r} has one MDP per task: choose a line-up of that world")
        self._check_solvers(where)

    def _check_solvers(self, where):
        """Validate the solver fields (a mapping of :data:`SOLVER_FIELDS` becomes a SolverSettings)."""
        try:
            if isinstance(self.solvers, Mapping):
                object.__setattr__(self, "solvers", SolverSettings(**self.solvers))
            if not isinstance(self.solvers, SolverSettings):
                raise ValidationError(f"solvers must be a SolverSettings; got {self.solvers!r}")
            for f in ("flat_solver", "flat_features_solver"):
                name = getattr(self, f)
                if not isinstance(name, str) or not name:
                    raise ValidationError(f"{f} must be a registered solver name; got {name!r}")
                with translate_solver_errors():  # unknown names list the available ones
                    solvers.get_solver(name)
        except FactIRLError as exc:
            raise type(exc)(where + str(exc)) from None
        except TypeError as exc:
            raise ValidationError(f"{where}solvers: {exc}") from None

    def points(self) -> list[tuple[int, int]]:
        """Sorted unique ``(n_tasks, demos_per_task)`` points of both sweeps."""
        pts = {(self.default_tasks, m) for m in self.demos_sweep}
        pts |= {(n, self.default_demos) for n in self.tasks_sweep}
        return sorted(pts)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict of every field, the solver settings flattened (:data:`SOLVER_FIELDS`)."""
        d = dataclasses.asdict(self)
        d["demos_sweep"], d["tasks_sweep"] = list(self.demos_sweep), list(self.tasks_sweep)
        del d["solvers"]
        d.update(self.solvers.fields())  # the four fields, and a later one only when set: the keys unchanged
        return d

    def fingerprint(self) -> str:
        """Short hash of every field that changes a run's result (all but name, n_seeds and the
        solvers, which are in the runs' keys).

        The fields added after the paper's preset (:data:`LATER_FIELDS`: ``world``, ``lineup``,
        ``planner``, ...) enter it only when they differ from their defaults, so the paper's
        runs keep the keys they had before these fields existed.
        """
        d = self.to_dict()
        for f in ("name", "n_seeds", *SOLVER_FIELDS):
            del d[f]
        for f, default in LATER_FIELDS.items():
            if d[f] == default:
                del d[f]
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:10]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Preset:
        """Inverse of :meth:`to_dict`."""
        d = dict(d)
        for f in ("demos_sweep", "tasks_sweep"):
            if f in d:
                d[f] = tuple(d[f])
        flat_solvers = {f: d.pop(f) for f in SOLVER_FIELDS if f in d}
        if flat_solvers:
            d["solvers"] = flat_solvers
        try:
            return cls(**d)
        except TypeError as exc:
            raise ValidationError(f"not a preset: {exc}") from None


#: the ``fast`` preset's solvers and stopping rules, chosen from runs of its default
#: point (100 tasks x 10 demos, seed 0, one run each, two at a time on the 2-core machine):
#: Gauss-Newton QP H-steps (Clarabel; transfer too), L-BFGS D-steps, FactIRL stopping at a
#: gradient norm 1e-3 x its initial one or a relative decrease 1e-4 per outer iteration, L-BFGS
#: for the tabular flat fits and Gauss-Newton QP steps for the flat fits on features (5-15
#: weights per task; on 400 tabular weights per task the cvxpy block QP does not fit in memory).
#: The run took 97 s against 444 s for armijo | gn-cg with the paper's flat solvers (whose
#: random-init fit ran its 100 outer iterations of CG products) and kept every ordering of the paper.
#: The PCA start shrinks while the loss decreases (``pca_shrink``): L-BFGS flat fits
#: reach larger rewards than Armijo's, whose truncation can start FactIRL in a saturated region.
FAST_SOLVERS: dict[str, Any] = dict(solvers=SolverSettings("gn-qp-clarabel", d_solver="lbfgs"), inner_steps=2, fact_max_iter=50, fact_gtol=1e-3,
                    fact_tol=1e-4, flat_solver="lbfgs", flat_features_solver="gn-qp-clarabel", pca_shrink=True)

#: the Objectworld presets' solvers: the ``fast`` preset's, with L-BFGS for the flat fits on features
#: too (Levine's 217 features at 32x32 make a Gauss-Newton block QP too large to compile)
OBJECTWORLD_SOLVERS: dict[str, Any] = dict(FAST_SOLVERS, flat_features_solver="lbfgs")

#: the full-size Objectworld presets' (``objectworld``, ``objectworld-per-task``): FactIRL's joint scheme
#: (L-BFGS on the dictionary and coefficients together) and GradIRL's saturation rule in every flat fit
#: (``flat_stol = 1e-5``, the library's default): at 30 tasks a map per task, with FactIRL's L-BFGS flat start,
#: 0.36-0.44x the CPU of the alternation from an Armijo start, at a lower train and new-maps deviation; the
#: one-demonstration test tasks' flat fits stop by their own rule in a third of the CPU (``results/fit-speed/``)
OBJECTWORLD_FULL_SOLVERS: dict[str, Any] = dict(OBJECTWORLD_SOLVERS, fact_scheme="joint", flat_stol=1e-5)

#: BabyAI: Armijo H-steps, L-BFGS D-steps and flat fits (faster than Gauss-Newton QP on 127 features), ``fast``'s rules
BABYAI_SOLVERS: dict[str, Any] = dict(FAST_SOLVERS, solvers=SolverSettings("armijo", d_solver="lbfgs"),
                                      flat_features_solver="lbfgs", n_primitives=8)
_BABYAI: dict[str, Any] = dict(world="babyai", lineup="babyai", n_seeds=1, **BABYAI_SOLVERS)

_OBJECTWORLD = Preset(
    name="objectworld",
    world="objectworld",
    lineup="objectworld",
    grid_size=32,
    demo_length=16,
    demos_sweep=(32,),
    tasks_sweep=(10, 20, 50, 100),
    default_tasks=100,
    default_demos=32,
    n_test_tasks=100,
    n_seeds=3,
    **OBJECTWORLD_FULL_SOLVERS,
)
_OBJECTWORLD_QUICK = Preset(
    name="objectworld-quick",
    world="objectworld",
    lineup="objectworld",
    grid_size=16,
    demo_length=16,
    demos_sweep=(16,),
    tasks_sweep=(5, 20),
    default_tasks=20,
    default_demos=16,
    n_test_tasks=20,
    flat_max_iter=40,
    transfer_max_iter=40,
    n_seeds=3,
    **dict(OBJECTWORLD_SOLVERS, fact_max_iter=15),
)


def _on_own_maps(preset: Preset, name: str, **changes: Any) -> Preset:
    """``preset`` with every task on its own map (world and line-up ``"objectworld-per-task"``)."""
    return dataclasses.replace(preset, name=name, world="objectworld-per-task", lineup="objectworld-per-task", **changes)


PRESETS = {
    "paper": Preset(name="paper"),
    "fast": Preset(name="fast", **FAST_SOLVERS),
    "quick": Preset(
        name="quick",
        grid_size=8,
        demos_sweep=(3, 10),
        tasks_sweep=(5, 40),
        default_tasks=40,
        default_demos=10,
        n_test_tasks=15,
        n_features_from_examples=10,
        flat_max_iter=50,
        fact_max_iter=30,
        transfer_max_iter=50,
        n_seeds=1,
    ),
    "test": Preset(
        name="test",
        demos_sweep=(10,),
        tasks_sweep=(50,),
        default_tasks=50,
        default_demos=10,
        n_test_tasks=50,
        n_seeds=1,
    ),
    "objectworld": _OBJECTWORLD,
    "objectworld-quick": _OBJECTWORLD_QUICK,
    "objectworld-tiny": Preset(
        name="objectworld-tiny",
        world="objectworld",
        lineup="objectworld",
        grid_size=8,
        object_density=0.15,
        demo_length=8,
        demos_sweep=(4,),
        tasks_sweep=(3, 6),
        default_tasks=6,
        default_demos=4,
        n_test_tasks=4,
        flat_max_iter=8,
        transfer_max_iter=8,
        n_seeds=1,
        **dict(OBJECTWORLD_SOLVERS, fact_max_iter=3),
    ),
    "objectworld-per-task": _on_own_maps(_OBJECTWORLD, "objectworld-per-task"),
    "objectworld-per-task-quick": _on_own_maps(_OBJECTWORLD_QUICK, "objectworld-per-task-quick", grid_size=8,
                                               object_density=0.15),
    "babyai": Preset(name="babyai", **dict(_BABYAI, demos_sweep=(4,), tasks_sweep=(10, 30, 100), default_tasks=100,
                                           default_demos=4, n_test_tasks=100, n_seeds=3)),
    "babyai-large": Preset(name="babyai-large", **dict(_BABYAI, world="babyai-large", demos_sweep=(2,), tasks_sweep=(10, 30),
                                                       default_tasks=30, default_demos=2, n_test_tasks=30)),
    "babyai-quick": Preset(name="babyai-quick", **dict(_BABYAI, demos_sweep=(3,), tasks_sweep=(12,), default_tasks=12,
                                                       default_demos=3, n_test_tasks=10, flat_max_iter=40,
                                                       transfer_max_iter=40, fact_max_iter=10)),
    "tiny": Preset(
        name="tiny",
        grid_size=5,
        demos_sweep=(2, 5),
        tasks_sweep=(4, 8),
        default_tasks=8,
        default_demos=5,
        n_test_tasks=6,
        n_features_from_examples=4,
        flat_max_iter=10,
        fact_max_iter=5,
        inner_steps=2,
        transfer_max_iter=10,
        n_seeds=2,
    ),
}

#: the search route of the sharing presets' adaptive learner: FactIRL's default (the other presets
#: keep the race their committed tables were made with)
_SHARING_ROUTE = DEFAULT_ROUTE
#: what the sharing presets change: the route, and every FactIRL transfer with FactIRL's default
#: saturation rule (``transfer_stol``, :data:`~factirl_opt.learners.transfer.TRANSFER_STOL`)
_SHARING: dict[str, Any] = dict(sharing_route=_SHARING_ROUTE, transfer_stol=TRANSFER_STOL)
#: "which learner when": flat, factorial (the preset's k) and the adaptive learner
#: (k and the residual penalty chosen by validation), 3 seeds, on the paper's grid at 5, 20 and
#: 100 training tasks, on both quick Objectworld presets, on BabyAI GoToLocal and GoToOpen
SHARING_PRESETS = ("sharing-grid", "sharing-objectworld-quick", "sharing-objectworld-per-task-quick", "sharing-babyai",
                   "sharing-babyai-large")
PRESETS.update({
    "sharing-grid": Preset(name="sharing-grid", lineup="sharing", demos_sweep=(10,), tasks_sweep=(5, 20, 100),
                           **_SHARING),
    "sharing-objectworld-quick": dataclasses.replace(PRESETS["objectworld-quick"], name="sharing-objectworld-quick",
                                                     lineup="objectworld-sharing", **_SHARING),
    "sharing-objectworld-per-task-quick": dataclasses.replace(PRESETS["objectworld-per-task-quick"],
                                                              name="sharing-objectworld-per-task-quick",
                                                              lineup="objectworld-per-task-sharing",
                                                              **_SHARING),
    "sharing-babyai": dataclasses.replace(PRESETS["babyai"], name="sharing-babyai", lineup="babyai-sharing",
                                          tasks_sweep=(10, 30), default_tasks=30, **_SHARING),
    "sharing-babyai-large": dataclasses.replace(PRESETS["babyai-large"], name="sharing-babyai-large",
                                                lineup="babyai-sharing", tasks_sweep=(10,), default_tasks=10, n_seeds=3,
                                                **_SHARING),
    "sharing-tiny": dataclasses.replace(PRESETS["tiny"], name="sharing-tiny", lineup="sharing", **_SHARING),
})


#: one line per preset, for ``factirl-opt reproduce --help``
PRESET_DESCRIPTIONS = {
    "paper": "the paper's section 4: 10x10 grid, 9 sweep points, 100 test tasks, 3 seeds (49 min with --jobs 2 on 2 cores beside other jobs: results/manifest.json)",
    "fast": "the paper's section 4 with the factorial learner's faster solvers (FAST_SOLVERS; same world, sweeps, "
            "seeds and budgets; 24 min with --jobs 2 on 2 cores beside other jobs: results/fast/manifest.json)",
    "quick": "every learner and figure: 8x8 grid, 40 tasks, short budgets, 1 seed (14 s of wall time with --jobs 1 in a "
             "fresh virtualenv: results/setup/quick-manifest.json)",
    "test": "the paper's world at one point (50 tasks x 10 demos), 1 seed: the regression tests' orderings",
    "objectworld": "ELIRL's multi-task Objectworld: 32x32, 100 training tasks x 32 demos of 16 steps, tasks sweep "
                   "10-100, 100 test tasks, 3 seeds (57 min with --jobs 1 beside other jobs: "
                   "results/objectworld/manifest.json)",
    "objectworld-quick": "Objectworld at 16x16: 20 training tasks x 16 demos, 20 test tasks, short budgets, 3 seeds "
                         "(3 min with --jobs 1: results/objectworld-quick/manifest.json)",
    "objectworld-tiny": "an 8x8 Objectworld, a few tasks and iterations: seconds; tests the machinery",
    "objectworld-per-task": "ELIRL's benchmark as its script runs it: every task on its own 32x32 map, 100 training "
                            "tasks x 32 demos, tasks sweep 10-100, 100 test tasks on unseen maps, scored on own and "
                            "fresh maps, 3 seeds (56 min with --jobs 2 beside other jobs: "
                            "results/objectworld-per-task/manifest.json)",
    "objectworld-per-task-quick": "a map per task at 8x8: 20 training tasks x 16 demos, 20 test tasks, short budgets, "
                                  "3 seeds",
    "babyai": "BabyAI-GoToLocal-v0: a layout per task, the bot's demonstrations, 10/30/100 training layouts, 100 test "
              "layouts with one demonstration each, success rate in the environment, 3 seeds (16 min with --jobs 1: "
              "results/babyai/manifest.json)",
    "babyai-large": "BabyAI-GoToOpen-v0 (about 1,250 states per layout): 10/30 training layouts x 2 demos, 30 test "
                    "layouts, 1 seed (7 min with --jobs 1: results/babyai/large/manifest.json)",
    "babyai-quick": "BabyAI-GoToLocal-v0: 12 training layouts x 3 demos, 10 test layouts, short budgets, 1 seed",
    "tiny": "a 5x5 grid, a few tasks and iterations, 2 seeds: seconds; tests the machinery, its scores mean nothing",
    "sharing-grid": "which learner when: flat, factorial (k = 5) and adaptive (k and residual penalty by validation) "
                    "on the paper's grid at 5, 20 and 100 training tasks x 10 demos, 100 test tasks, 3 seeds",
    "sharing-objectworld-quick": "which learner when on objectworld-quick (one 16x16 map), on features, 3 seeds",
    "sharing-objectworld-per-task-quick": "which learner when on objectworld-per-task-quick (a map per task), on "
                                          "features, 3 seeds",
    "sharing-babyai": "which learner when on BabyAI-GoToLocal-v0: 10 and 30 training layouts x 4 demos, 100 test "
                      "layouts, success rate in the environment, 3 seeds",
    "sharing-babyai-large": "which learner when on BabyAI-GoToOpen-v0: 10 training layouts x 2 demos, 30 test layouts, "
                            "3 seeds",
    "sharing-tiny": "which learner when on the tiny grid: seconds; tests the machinery",
}


def get_preset(preset: str | Preset) -> Preset:
    """A :class:`Preset` from its name (or a Preset, returned as is)."""
    if isinstance(preset, Preset):
        return preset
    if isinstance(preset, str) and preset in PRESETS:
        return PRESETS[preset]
    raise ValidationError(f"unknown preset {preset!r}; available: {', '.join(PRESETS)}")
