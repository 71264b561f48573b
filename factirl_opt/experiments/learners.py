"""The learners of the experiments, as data: named line-ups of builders.

A *line-up* is an ordered table of :class:`Learner` rows ``(split, name, build, version,
needs)``. ``build(gt, preset, ctx)`` fits one learner on the ground truth's ``split`` tasks and
returns a :class:`Fit` (learnt rewards, final loss per task, Q* evaluations); the runner times
and scores it. Rows run in table order and share a :class:`RunContext` (the run's solver
settings, random streams, and what earlier rows learnt), so a learner that builds on another
(the factorial transfer on the factorial fit) names it in ``needs``. A new learner (another
objective, features, another D-step solver) is a new row or a new line-up, not a new code
path; bump a builder's ``version`` when its behaviour changes, so cached runs made with the
old one are recomputed (:mod:`.store`).

Line-up ``"paper"`` (the paper's section 4, names as in the paper):

train tasks (``split = "train"``)
    ``flat`` (GradIRL, tabular); ``flat, ground truth`` (GradIRL with the true dictionary as
    features); ``flat, PCA features`` (GradIRL with the first ``n_pca_components`` components
    of the uncentred PCA of the flat rewards); ``factorial`` (FactIRL initialised by that PCA,
    the paper's heuristic, reusing the flat rewards); ``factorial, random init``.
test tasks (``split = "test"``, one demonstration each)
    ``flat`` (from scratch); ``factorial`` (``FactIRL.transfer`` with the dictionary learnt by
    ``factorial``); ``flat, features from ex.`` (GradIRL with ``n_features_from_examples``
    learnt flat training rewards, chosen at random, as features); ``flat, PCA features`` (the
    training PCA components); ``flat, ground truth`` (the floor).

Line-up ``"objectworld"`` (issue 11; the world's base features are Levine's discrete distance
features, the true dictionary ELIRL's primitives):

train tasks
    ``flat`` (GradIRL, tabular); ``flat, features`` (GradIRL on the base features); ``flat,
    ground truth`` (GradIRL with the true primitives as features: the floor); ``factorial``
    (FactIRL, tabular, from the PCA of ``flat``); ``factorial, features`` (FactIRL with
    ``R_i = Phi D h_i`` on the base features, from the PCA of the feature weights of ``flat,
    features``); ``factorial, features, random init``.
test tasks (one demonstration each)
    ``flat``; ``flat, features``; ``factorial`` and ``factorial, features`` (``transfer`` of
    the training dictionaries); ``flat, ground truth``.

Line-ups ``"paper+mce"`` and ``"objectworld+mce"`` (issue 12): the line-up, plus a flat and a
factorial learner on the maximum causal entropy likelihood (``objective="mce"``), train and
test: ``flat MCE`` (GradIRL), ``factorial MCE`` (FactIRL from the PCA of ``flat MCE``'s
rewards; its ``transfer`` on the test tasks); on Objectworld both on the base features
(``flat MCE, features``, ``factorial MCE, features``). The Gauss-Newton solvers need a
least-squares objective: where a run names one, the MCE learners take L-BFGS steps
(:data:`GRADIENT_FALLBACK`, :func:`factorial_options`).

Figure 3 shows the value functions of the line-up's ``value_maps`` test learners.
"""

import collections
import dataclasses
import json
from typing import Callable

import numpy as np

import solvers

from ..exceptions import ValidationError, translate_solver_errors
from ..factirl import FactIRL, pca_dictionary
from ..gradirl import GradIRL, check_solver_applies

__all__ = ["Fit", "Learner", "Lineup", "LINEUPS", "RunContext", "get_lineup", "factorial_options",
           "solver_settings", "decode_options"]

#: what a builder returns: rewards (n, S, A), final loss per task (n,), Q* evaluations (int)
Fit = collections.namedtuple("Fit", "rewards loss n_evaluations")

#: the objective of the paper's learners (eq. 5)
DEFAULT_OBJECTIVE = "policy-matching"

#: the solver a learner on an objective without residuals (``"mce"``) takes where the run or
#: preset names a Gauss-Newton one: the quasi-Newton counterpart, which needs only gradients
GRADIENT_FALLBACK = "lbfgs"

#: the learners' random streams, spawned in this order from the ground truth's ``learner_rng``
#: (append new names at the end: the existing streams then stay the same)
STREAMS = ("pca", "random_init", "examples")


@dataclasses.dataclass(frozen=True)
class Learner:
    """One row of a line-up.

    Parameters
    ----------
    split : {"train", "test"}
    name : str
        The learner's name in the tables and figures.
    build : callable
        ``build(gt, preset, ctx) -> Fit``.
    version : int
        Version of the builder's behaviour (part of a cached run's key).
    needs : tuple of (split, name)
        Rows that must run before this one (their results are read from ``ctx``).
    per_seed : bool
        The fit depends only on the seed's world and test tasks, not on the sweep point (a test
        row that reads nothing from training: ``flat`` from scratch, on fixed features): the
        runner fits it once per seed and worker and scores it in every run of that seed
        (:func:`.runner.run_one`'s ``reuse``).
    """

    split: str
    name: str
    build: Callable
    version: int = 1
    needs: tuple = ()
    per_seed: bool = False


@dataclasses.dataclass(frozen=True)
class Lineup:
    """A named, ordered table of learners, and the test learners figure 3 shows.

    ``worlds``: the names of the worlds (:data:`.worlds.WORLDS`) the line-up runs in (empty:
    any world); e.g. a line-up with learners on base features needs a world that has them.
    """

    name: str
    learners: tuple
    value_maps: tuple = ()
    worlds: tuple = ()

    def __post_init__(self):
        seen = set()
        for lr in self.learners:
            if lr.split not in ("train", "test"):
                raise ValidationError(f"line-up {self.name!r}: split must be 'train' or 'test'; got {lr.split!r}")
            if (lr.split, lr.name) in seen:
                raise ValidationError(f"line-up {self.name!r}: duplicate learner {lr.split}: {lr.name}")
            if lr.per_seed and (lr.split != "test" or lr.needs):
                raise ValidationError(f"line-up {self.name!r}: {lr.split}: {lr.name} cannot be per_seed: only a test row "
                                      "that needs no other row is the same at every point of a seed")
            missing = [n for n in lr.needs if tuple(n) not in seen]
            if missing:
                raise ValidationError(f"line-up {self.name!r}: {lr.split}: {lr.name} needs {missing} earlier in the line-up")
            seen.add((lr.split, lr.name))
        for name in self.value_maps:
            if ("test", name) not in seen:
                raise ValidationError(f"line-up {self.name!r}: value map of unknown test learner {name!r}")

    def names(self, split):
        """Learner names of one split, in line-up order."""
        return tuple(lr.name for lr in self.learners if lr.split == split)

    def fingerprint(self):
        """``[[split, name, version], ...]``: what identifies the line-up in a cached run."""
        return [[lr.split, lr.name, lr.version] for lr in self.learners]


class RunContext:
    """What the learners of one run share.

    Attributes
    ----------
    spec : RunSpec
        The run (point, seed, solver settings).
    split : str
        Split of the row being built (set by the runner).
    rngs : dict
        Named random streams (:data:`STREAMS`), spawned from ``gt.learner_rng``.
    rewards : dict
        ``(split, name) -> rewards (n, S, A)`` of the rows already built.
    models : dict
        Fitted estimators that later rows build on (e.g. ``"factorial"``).
    """

    def __init__(self, gt, spec):
        self.spec = spec
        self.split = None
        self.rngs = dict(zip(STREAMS, gt.learner_rng.spawn(len(STREAMS))))
        self.rewards = {}
        self.models = {}
        self._shared = {}

    def shared(self, name, make):
        """``make()``, computed once per run and shared by the rows that ask for ``name``."""
        if name not in self._shared:
            self._shared[name] = make()
        return self._shared[name]


def _canonical(options):
    return json.dumps(options, sort_keys=True, separators=(",", ":")) if options else ""


def decode_options(text):
    """Solver options stored as canonical JSON (``""``: none), as a dict."""
    return json.loads(text) if text else {}



def _check_options(options, name):
    if options is None:
        return {}
    if not isinstance(options, dict) or not all(isinstance(k, str) and k for k in options):
        raise ValidationError(f"{name} must be a dict of option names to values; got {options!r}")
    try:
        json.dumps(options)
    except (TypeError, ValueError):
        raise ValidationError(f"{name} must hold plain values (numbers, strings, booleans, lists); got {options!r}") from None
    return options


def solver_settings(h_solver="armijo", h_solver_options=None, d_solver=None, d_solver_options=None):
    """Validate the factorial learner's solver settings; returns them as RunSpec (and Preset) fields.

    Every name must be registered (:func:`solvers.available_solvers`) and accept its options;
    a D-step solver needs a FactIRL with a ``d_solver`` parameter.

    Returns
    -------
    dict
        ``h_solver``, ``h_solver_options``, ``d_solver``, ``d_solver_options``: the names (``""``
        for FactIRL's default D-step) and the options as canonical JSON (``""``: none).
    """
    out = {}
    for role, name, options in (("h", h_solver, h_solver_options), ("d", d_solver, d_solver_options)):
        options = _check_options(options, f"{role}_solver_options")
        if role == "d" and name is None:
            if options:
                raise ValidationError("d_solver_options given without d_solver")
            out.update(d_solver="", d_solver_options="")
            continue
        if not isinstance(name, str) or not name:
            raise ValidationError(f"{role}_solver must be a registered solver name; got {name!r}")
        with translate_solver_errors():  # the library's exceptions: unknown names list the available ones
            solvers.get_solver(name, **options)
        out.update({f"{role}_solver": name, f"{role}_solver_options": _canonical(options)})
    return out


def _applies(name, options, objective):
    """Whether the registered solver ``name`` applies to ``objective`` (Gauss-Newton ones need residuals)."""
    try:
        check_solver_applies(solvers.get_solver(name, **options), objective, "solver")
    except ValidationError:
        return False
    return True


def factorial_options(preset, spec, objective=DEFAULT_OBJECTIVE):
    """Keyword arguments of every FactIRL of a run: the preset's budgets, the run's solver settings.

    Solver options and the D-step solver are passed only when the run names them, so a run
    with the defaults builds exactly the FactIRL it always did. A learner on an objective
    without residuals (``"mce"``) cannot take a Gauss-Newton solver (``gn-qp-*``, ``gn-cg``):
    where the run names one, that learner takes :data:`GRADIENT_FALLBACK`'s steps instead
    (its table rows keep the run's solver label).
    """
    kw = dict(n_primitives=preset.n_primitives, beta=preset.beta, max_iter=preset.fact_max_iter, gtol=preset.fact_gtol,
              tol=preset.fact_tol, pca_shrink=preset.pca_shrink,
              inner_steps=preset.inner_steps, flat_max_iter=preset.flat_max_iter,
              transfer_max_iter=preset.transfer_max_iter, objective=objective, planner=preset.planner)
    roles = [("h", spec.h_solver, spec.h_options())]
    if spec.d_solver:
        roles.append(("d", spec.d_solver, spec.d_options()))
    for role, name, options in roles:
        if not _applies(name, options, objective):
            name, options = GRADIENT_FALLBACK, {}
        kw[f"{role}_solver"] = name
        if options:
            kw[f"{role}_solver_options"] = options
    return kw


# --- builders: (gt, preset, ctx) -> Fit ---------------------------------------------------


def _gradirl(gt, preset, ctx, features=None, objective=DEFAULT_OBJECTIVE):
    solver = preset.flat_solver if features is None else preset.flat_features_solver
    solver = solver if _applies(solver, {}, objective) else GRADIENT_FALLBACK
    model = GradIRL(beta=preset.beta, features=features, max_iter=preset.flat_max_iter, solver=solver,
                    objective=objective, planner=preset.planner)
    model.fit(gt.mdp, gt.demos(ctx.split))
    return Fit(model.rewards_, model.loss_, model.n_evaluations_)


def _pca_features(gt, preset, ctx):
    """The first components of the uncentred PCA of the flat training rewards, (S*A, k)."""

    def make():
        flat = ctx.rewards["train", "flat"]
        d = gt.mdp.n_params
        D, _ = pca_dictionary(flat.reshape(flat.shape[0], d), min(preset.n_pca_components, d), rng=ctx.rngs["pca"])
        return D

    return ctx.shared("pca_features", make)


def flat(gt, preset, ctx):
    """GradIRL, tabular rewards."""
    return _gradirl(gt, preset, ctx)


def flat_ground_truth(gt, preset, ctx):
    """GradIRL with the true dictionary as features (the floor)."""
    return _gradirl(gt, preset, ctx, gt.dictionary)


def flat_pca_features(gt, preset, ctx):
    """GradIRL with the PCA components of the flat training rewards as features."""
    return _gradirl(gt, preset, ctx, _pca_features(gt, preset, ctx))


def flat_features_from_examples(gt, preset, ctx):
    """GradIRL with ``n_features_from_examples`` learnt flat training rewards as features."""
    flat_train = ctx.rewards["train", "flat"]
    n = flat_train.shape[0]
    n_ex = min(preset.n_features_from_examples, n)
    chosen = np.sort(ctx.rngs["examples"].choice(n, size=n_ex, replace=False))
    return _gradirl(gt, preset, ctx, flat_train[chosen].reshape(n_ex, gt.mdp.n_params).T)


def _fit_factorial(gt, preset, ctx, name, init, flat=None, features=None, objective=DEFAULT_OBJECTIVE):
    """Fit a FactIRL on the training tasks, keep it in ``ctx.models[name]`` for its transfer.

    ``init="pca"`` starts from the uncentred PCA of the rewards learnt by the training row
    ``flat`` (random stream ``"pca"``); ``init="random"`` from a random start (stream
    ``"random_init"``). ``features``: the base features of ``R_i = Phi D h_i`` (None: tabular).
    """
    rng = ctx.rngs["pca" if init == "pca" else "random_init"]
    model = FactIRL(init=init, rng=rng, features=features, **factorial_options(preset, ctx.spec, objective))
    model.fit(gt.mdp, gt.train_demos, flat_rewards=None if flat is None else ctx.rewards["train", flat])
    ctx.models[name] = model
    return Fit(model.rewards_, model.loss_, model.n_evaluations_)


def _transfer(gt, ctx, name):
    """``FactIRL.transfer`` of the dictionary of the fitted model ``name`` to the test tasks."""
    model = ctx.models[name]
    model.transfer(gt.mdp, gt.test_demos)
    return Fit(model.transfer_rewards_, model.transfer_loss_, model.transfer_n_evaluations_)


def factorial(gt, preset, ctx):
    """FactIRL from the PCA of the flat training rewards (the paper's heuristic)."""
    return _fit_factorial(gt, preset, ctx, "factorial", "pca", flat="flat")


def factorial_random_init(gt, preset, ctx):
    """FactIRL from a random start."""
    return _fit_factorial(gt, preset, ctx, "factorial, random init", "random")


def factorial_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the training dictionary to the test tasks."""
    return _transfer(gt, ctx, "factorial")


def flat_features(gt, preset, ctx):
    """GradIRL on the world's base features (Objectworld: the discrete distance features)."""
    return _gradirl(gt, preset, ctx, gt.features)


def factorial_features(gt, preset, ctx):
    """FactIRL on the world's base features, from the PCA of ``flat, features``'s weights."""
    return _fit_factorial(gt, preset, ctx, "factorial, features", "pca", flat="flat, features", features=gt.features)


def factorial_features_random_init(gt, preset, ctx):
    """FactIRL on the world's base features from a random start."""
    return _fit_factorial(gt, preset, ctx, "factorial, features, random init", "random", features=gt.features)


def factorial_features_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the feature-space dictionary to the test tasks."""
    return _transfer(gt, ctx, "factorial, features")


def flat_mce(gt, preset, ctx):
    """GradIRL on the MCE likelihood, tabular rewards."""
    return _gradirl(gt, preset, ctx, objective="mce")


def factorial_mce(gt, preset, ctx):
    """FactIRL on the MCE likelihood, from the PCA of ``flat MCE``'s rewards."""
    return _fit_factorial(gt, preset, ctx, "factorial MCE", "pca", flat="flat MCE", objective="mce")


def factorial_mce_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the MCE dictionary to the test tasks (MCE likelihood)."""
    return _transfer(gt, ctx, "factorial MCE")


def flat_mce_features(gt, preset, ctx):
    """GradIRL on the MCE likelihood and the world's base features."""
    return _gradirl(gt, preset, ctx, gt.features, objective="mce")


def factorial_mce_features(gt, preset, ctx):
    """FactIRL on the MCE likelihood and the base features, from the PCA of ``flat MCE, features``."""
    return _fit_factorial(gt, preset, ctx, "factorial MCE, features", "pca", flat="flat MCE, features",
                          features=gt.features, objective="mce")


def factorial_mce_features_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the MCE feature-space dictionary to the test tasks."""
    return _transfer(gt, ctx, "factorial MCE, features")


def _extended(learners, train, test):
    """A line-up's learners with more train rows after its train rows and test rows at the end."""
    return tuple(lr for lr in learners if lr.split == "train") + train + tuple(lr for lr in learners if lr.split == "test") + test


def _mce_rows(suffix, flat_build, fact_build, transfer_build):
    """The train and test rows of a flat MCE learner and its factorial counterpart (names + ``suffix``)."""
    flat_name, fact_name = f"flat MCE{suffix}", f"factorial MCE{suffix}"
    train = (Learner("train", flat_name, flat_build),
             Learner("train", fact_name, fact_build, needs=(("train", flat_name),)))
    test = (Learner("test", flat_name, flat_build, per_seed=True),
            Learner("test", fact_name, transfer_build, needs=(("train", fact_name),)))
    return train, test


_TRAIN_FLAT = (("train", "flat"),)

#: line-up name (a preset's ``lineup``) -> Lineup
LINEUPS = {
    "paper": Lineup(
        name="paper",
        learners=(
            Learner("train", "flat", flat),
            Learner("train", "flat, ground truth", flat_ground_truth),
            Learner("train", "flat, PCA features", flat_pca_features, needs=_TRAIN_FLAT),
            Learner("train", "factorial", factorial, needs=_TRAIN_FLAT),
            Learner("train", "factorial, random init", factorial_random_init),
            Learner("test", "flat", flat, per_seed=True),
            Learner("test", "factorial", factorial_transfer, needs=(("train", "factorial"),)),
            Learner("test", "flat, features from ex.", flat_features_from_examples, needs=_TRAIN_FLAT),
            Learner("test", "flat, PCA features", flat_pca_features, needs=_TRAIN_FLAT),
            Learner("test", "flat, ground truth", flat_ground_truth, per_seed=True),
        ),
        value_maps=("flat", "factorial"),
    ),
    "objectworld": Lineup(
        name="objectworld",
        learners=(
            Learner("train", "flat", flat),
            Learner("train", "flat, features", flat_features),
            Learner("train", "flat, ground truth", flat_ground_truth),
            Learner("train", "factorial", factorial, needs=_TRAIN_FLAT),
            Learner("train", "factorial, features", factorial_features, needs=(("train", "flat, features"),)),
            Learner("train", "factorial, features, random init", factorial_features_random_init),
            Learner("test", "flat", flat, per_seed=True),
            Learner("test", "flat, features", flat_features, per_seed=True),
            Learner("test", "factorial", factorial_transfer, needs=(("train", "factorial"),)),
            Learner("test", "factorial, features", factorial_features_transfer,
                    needs=(("train", "factorial, features"),)),
            Learner("test", "flat, ground truth", flat_ground_truth, per_seed=True),
        ),
        value_maps=("flat, features", "factorial, features"),
        worlds=("objectworld",),
    ),
}
LINEUPS["paper+mce"] = Lineup(
    name="paper+mce",
    learners=_extended(LINEUPS["paper"].learners, *_mce_rows("", flat_mce, factorial_mce, factorial_mce_transfer)),
    value_maps=("flat", "factorial", "flat MCE", "factorial MCE"),
)
LINEUPS["objectworld+mce"] = Lineup(
    name="objectworld+mce",
    learners=_extended(LINEUPS["objectworld"].learners, *_mce_rows(", features", flat_mce_features, factorial_mce_features,
                                                                   factorial_mce_features_transfer)),
    value_maps=("flat, features", "factorial, features", "flat MCE, features", "factorial MCE, features"),
    worlds=("objectworld",),
)


def get_lineup(lineup):
    """A :class:`Lineup` from its name (or a Lineup, returned as is)."""
    if isinstance(lineup, Lineup):
        return lineup
    if isinstance(lineup, str) and lineup in LINEUPS:
        return LINEUPS[lineup]
    raise ValidationError(f"unknown learner line-up {lineup!r}; available: {', '.join(LINEUPS)}")
