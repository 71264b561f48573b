"""Progress reporting of long fits: user callbacks and an optional progress bar (internal)."""

import contextlib
import sys

from .exceptions import ValidationError

__all__ = ["fit_progress"]


@contextlib.contextmanager
def fit_progress(callback, verbose, total, desc, quantity="loss"):
    """Yield one ``report(iteration, loss)`` that calls ``callback`` and updates a tqdm bar.

    Parameters
    ----------
    callback : callable or None
        Called as ``callback(iteration, loss)`` after each iteration (``loss``: the total
        objective). Its return value is ignored.
    verbose : bool
        Show a progress bar on stderr (iterations, current loss).
    total : int
        Maximum iterations (the bar's length; a fit may stop earlier).
    desc : str
    quantity : str
        What the bar calls the value reported (the total loss, or EM's log-likelihood).
    """
    if callback is not None and not callable(callback):
        raise ValidationError(f"callback must be callable as callback(iteration, loss); got {type(callback).__name__}")
    if not isinstance(verbose, bool):
        raise ValidationError(f"verbose must be True or False; got {verbose!r}")
    bar = None
    if verbose:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, desc=desc, unit="it", file=sys.stderr, dynamic_ncols=True)

    def report(iteration, loss):
        if bar is not None:
            bar.update(iteration - bar.n)
            bar.set_postfix_str(f"{quantity} {loss:.6g}", refresh=False)
        if callback is not None:
            callback(iteration, loss)

    try:
        yield report
    finally:
        if bar is not None:
            bar.close()
