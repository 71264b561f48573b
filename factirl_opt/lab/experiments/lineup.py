"""The rows of a learner line-up: :class:`Learner`, :class:`Lineup`, what a builder returns
(:data:`Fit`) and what the rows of one run share (:class:`RunContext`).

The line-ups themselves (:data:`.learners.LINEUPS`) are data built from these types by
:mod:`.learners`, :mod:`.per_task` and :mod:`.babyai`.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import Any, Callable

from ...exceptions import ValidationError
from .learner_solvers import DEFAULT_OBJECTIVE, SOLVER_ROLES

__all__ = ["Fit", "Learner", "Lineup", "RunContext", "STREAMS"]

#: what a builder returns: rewards (n, S, A), final loss per task (n,), Q* evaluations (int)
Fit = collections.namedtuple("Fit", "rewards loss n_evaluations")


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
        The learner's name in the tables and figures (a constant of :mod:`.learner_names`).
    build : callable
        ``build(gt, preset, ctx) -> Fit``; the row being built is ``ctx.learner``.
    version : int
        Version of the builder's behaviour (part of a cached run's key).
    needs : tuple of (split, name)
        Rows that must run before this one (their results are read from ``ctx``).
    per_seed : bool
        The fit depends only on the seed's world and test tasks, not on the sweep point (a test
        row that reads nothing from training: ``flat`` from scratch, on fixed features): the
        runner fits it once per seed and worker and scores it in every run of that seed
        (:func:`.runner.run_one`'s ``reuse``).
    objective : str
        The loss the learner fits (``"policy-matching"``, eq. 5; ``"mce"``).
    solvers : {"flat", "flat features", "factorial"}
        Which solvers it takes (:data:`.learner_solvers.SOLVER_ROLES`); where they do not apply to the objective
        it takes :data:`GRADIENT_FALLBACK` (:func:`substitutions`).
    adaptive : bool
        A FactIRL row (``solvers="factorial"``) whose learner chooses k and the residual
        penalty by validation (``n_primitives="auto", residual_penalty="auto"``;
        :func:`.learner_solvers.factorial_options`), its transfer with what it chose.
    """

    split: str
    name: str
    build: Callable[..., Fit]
    version: int = 1
    needs: tuple = ()
    per_seed: bool = False
    objective: str = DEFAULT_OBJECTIVE
    solvers: str = "flat"
    adaptive: bool = False

    def __post_init__(self) -> None:
        if self.solvers not in SOLVER_ROLES:
            raise ValidationError(f"learner {self.split}: {self.name}: solvers must be one of "
                                  f"{', '.join(SOLVER_ROLES)}; got {self.solvers!r}")
        if self.adaptive and self.solvers != "factorial":
            raise ValidationError(f"learner {self.split}: {self.name}: only a FactIRL row (solvers='factorial') can be "
                                  f"adaptive; got solvers={self.solvers!r}")


@dataclasses.dataclass(frozen=True)
class Lineup:
    """A named, ordered table of learners, and the test learners figure 3 shows.

    ``worlds``: the names of the worlds (:data:`.worlds.WORLDS`) the line-up runs in (empty:
    any world); e.g. a line-up with learners on base features needs a world that has them.
    ``one_mdp``: its learners plan every task on the one MDP of the ground truth
    (``GroundTruth.mdp``), so it does not run in a world of per-task MDPs
    (:data:`.worlds.PER_TASK_WORLDS`).
    """

    name: str
    learners: tuple
    value_maps: tuple = ()
    worlds: tuple = ()
    one_mdp: bool = False

    def __post_init__(self) -> None:
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

    def names(self, split: str) -> tuple[str, ...]:
        """Learner names of one split, in line-up order."""
        return tuple(lr.name for lr in self.learners if lr.split == split)

    def fingerprint(self) -> list[list]:
        """``[[split, name, version], ...]``: what identifies the line-up in a cached run."""
        return [[lr.split, lr.name, lr.version] for lr in self.learners]


class RunContext:
    """What the learners of one run share.

    Attributes
    ----------
    spec : RunSpec
        The run (point, seed, solver settings).
    learner : Learner
        The row being built (set by the runner); ``split`` is its split.
    rngs : dict
        Named random streams (:data:`STREAMS`), spawned from ``gt.learner_rng``.
    rewards : dict
        ``(split, name) -> rewards (n, S, A)`` of the rows already built.
    models : dict
        Fitted estimators that later rows build on (e.g. ``"factorial"``).
    """

    def __init__(self, gt: Any, spec: Any) -> None:
        self.spec = spec
        self.learner: Learner | None = None
        self.rngs = dict(zip(STREAMS, gt.learner_rng.spawn(len(STREAMS))))
        self.rewards: dict = {}
        self.models: dict = {}
        self._shared: dict = {}

    @property
    def split(self) -> str | None:
        """Split of the row being built."""
        return None if self.learner is None else self.learner.split

    def shared(self, name: str, make: Callable[[], Any]) -> Any:
        """``make()``, computed once per run and shared by the rows that ask for ``name``."""
        if name not in self._shared:
            self._shared[name] = make()
        return self._shared[name]
