"""The stopping rules of the step solvers and of the learners' outer loops (docs/maths.md §5).

Three rules, each with one home here; a run stops ("converged") as soon as one holds.

**Relative decrease** (:func:`has_converged`, tolerance ``tol``). A run stops early when the
*relative decrease* of its total objective over one step,

    ``(f_prev - f_curr) / max(|f_prev|, tiny)``,

is between 0 and ``tol``, where ``tiny`` is the smallest positive float (so ``f_prev = 0``
divides by ``tiny``, not by zero). The rule is written multiplied out, ``0 <= f_prev - f_curr
<= tol * max(|f_prev|, tiny)``, so that no division can overflow. A rise of the objective is
not convergence (a learner's outer loop goes on and keeps its best point; the step solvers
never rise). With ``tol = 0`` a run stops early only when the objective stays exactly equal.
The total objective is the sum over rows (tasks) of each row's loss plus any penalty of the
solver.

**Gradient norm** (:func:`gradient_converged`, tolerance ``gtol``). A run stops when the norm
of the first-order optimality measure of its total objective (the gradient; for a constrained
or penalised solver the projected gradient or the minimum-norm subgradient,
:meth:`solvers.StepSolver.optimality`) is at most ``gtol`` times its value at the start of the
run: ``||g|| <= gtol * ||g_0||``. Relative to the start, so the rule does not depend on the
scale of the objective or of the parameters. It stops runs whose objective keeps decreasing
geometrically toward a minimum at infinity (the relative decrease never becomes small there;
for the IRL objectives: Boltzmann policies saturating as the rewards grow) and runs that reach a
stationary point. ``gtol = 0`` stops only at an exactly zero gradient.

**Saturation** (:func:`has_saturated`, tolerance ``stol``). A run stops early when the
decrease of its total objective over one step is between 0 and ``stol`` times its decrease since
the start of the run:

    ``0 <= f_{k-1} - f_k <= stol * (f_0 - f_k)``.

The step is measured against the progress the run made, not against the current objective (as
the relative decrease is): the loss has saturated when a step adds a fraction of at most
``stol`` to what the run achieved. So it stops a run whose objective falls geometrically toward
a minimum at infinity (the relative decrease stays of order one there) once its objective is
about ``stol`` of its start, without a gradient and whatever the gradient does; a run with a
positive minimum above half its start, ``f_k >= f_0 - f_k``, meets the relative decrease with
the same tolerance first. It depends neither on the scale of the objective nor on a constant
added to it. ``stol = 0`` turns it off: it then holds only when the objective stayed exactly
equal, where the relative decrease has already stopped the run.

**Per row** (:mod:`solvers.separable`), the three rules apply to each row's own objective and
optimality measure. There the gradient rule is the one that stops a row whose objective tends
to 0, its infimum (a reward that matches its demonstrations exactly): the relative decrease
of a row is measured against the row's own, vanishing objective and stays large, while in a
total the rows near 0 weigh nothing and the rows with a positive minimum decide. So a
separable run that should stop such rows needs ``gtol > 0`` (the learners' default is 1e-4)
or ``stol > 0``, which measures the row's decrease against its own progress (GradIRL's default
is 1e-5); with both 0 they run to ``max_iter`` (docs/maths.md §5, "Saturation").
"""

from __future__ import annotations

import numpy as np

from ._validation import check_number

__all__ = ["relative_decrease", "has_converged", "gradient_converged", "has_saturated"]

_TINY = np.finfo(np.float64).tiny


def _check_values(prev, current):
    prev = check_number(prev, "prev", "relative decrease")
    current = check_number(current, "current", "relative decrease")
    return float(prev), float(current)


def relative_decrease(prev: float, current: float) -> float:
    """Relative decrease ``(prev - current) / max(|prev|, tiny)`` of a total objective.

    Parameters
    ----------
    prev, current : float
        Total objective before and after a step; finite.

    Returns
    -------
    float
        Positive when the objective went down, 0 when it stayed equal, negative when it went
        up (``-current / tiny`` when ``prev`` is 0; +-inf if that overflows).

    Raises
    ------
    SolverOptionError
        When a value is not a finite number.
    """
    prev, current = _check_values(prev, current)
    with np.errstate(over="ignore"):
        return float((prev - current) / max(abs(prev), _TINY))


def has_converged(prev: float, current: float, tol: float) -> bool:
    """Whether a step from ``prev`` to ``current`` decreased the objective, by at most ``tol``
    relatively: ``0 <= prev - current <= tol * max(|prev|, tiny)``.

    Parameters
    ----------
    prev, current : float
        Total objective before and after a step; finite.
    tol : float
        ``>= 0``. ``tol = 0`` only stops when the objective stays equal; a rise never stops.

    Returns
    -------
    bool

    Raises
    ------
    SolverOptionError
        When a value is not a finite number or ``tol < 0``.
    """
    prev, current = _check_values(prev, current)
    tol = check_number(tol, "tol", "relative decrease", low=0.0)
    with np.errstate(over="ignore"):
        return bool(0.0 <= prev - current <= tol * max(abs(prev), _TINY))


def gradient_converged(norm: float, initial: float, gtol: float) -> bool:
    """Whether the gradient norm has fallen to at most ``gtol`` times its initial value.

    Parameters
    ----------
    norm : float
        Norm of the first-order optimality measure now, >= 0 (inf when it overflowed).
    initial : float
        Its norm at the start of the run, >= 0 (inf when it overflowed).
    gtol : float
        ``>= 0``.

    Returns
    -------
    bool
        ``norm <= gtol * initial``; False when either norm is not finite (an overflowed
        gradient says nothing about convergence).

    Raises
    ------
    SolverOptionError
        When a norm is not a number >= 0 (NaN included) or ``gtol`` is not a finite number >= 0.
    """
    gtol = check_number(gtol, "gtol", "gradient rule", low=0.0)
    for value, name in ((norm, "norm"), (initial, "initial")):
        if value != np.inf:
            check_number(value, name, "gradient rule", low=0.0)
    return bool(np.isfinite(norm) and np.isfinite(initial) and norm <= gtol * initial)


def has_saturated(start: float, prev: float, current: float, stol: float) -> bool:
    """Whether a step from ``prev`` to ``current`` decreased the objective by at most ``stol``
    times its decrease since ``start``: ``0 <= prev - current <= stol * (start - current)``.

    Parameters
    ----------
    start : float
        The objective at the start of the run, ``f_0``; finite.
    prev, current : float
        The objective before and after the step; finite.
    stol : float
        ``>= 0``. ``stol = 0`` only stops when the objective stays equal; a rise never stops.

    Returns
    -------
    bool

    Raises
    ------
    SolverOptionError
        When a value is not a finite number or ``stol < 0``.
    """
    start, prev, current = (float(check_number(v, name, "saturation rule"))
                            for v, name in ((start, "start"), (prev, "prev"), (current, "current")))
    stol = check_number(stol, "stol", "saturation rule", low=0.0)
    with np.errstate(over="ignore"):
        return bool(0.0 <= prev - current <= stol * (start - current))
