"""The library's checks of scalar arguments, public for code built on it.

The estimators and functions of the library validate their scalar parameters with these
functions; the experiment harness (:mod:`factirl_opt.lab`) and user code that takes parameters
of its own (presets, scripts, extensions) use them too, so that a bad value gets the library's
rule and message wherever it enters. Each returns the value as a plain Python type and raises
:class:`~factirl_opt.exceptions.ValidationError` naming the argument, the rule and the value given.

Examples
--------
>>> from factirl_opt.validation import check_int, check_real
>>> check_int(3, "n_seeds", minimum=1)
3
>>> check_real(0.9, "gamma", 0.0, 1.0, high_open=True)
0.9
>>> check_int(0, "n_seeds", minimum=1)
Traceback (most recent call last):
...
factirl_opt.exceptions.ValidationError: n_seeds must be an integer >= 1; got 0
"""

from ._validation import as_rng, check_bool, check_int, check_probability, check_real

__all__ = ["check_int", "check_real", "check_probability", "check_bool", "as_rng"]
