"""``factirl-opt ARGS...`` with every MaxIterWarning recorded: each one goes to LOG, one line.

The benchmarks and the experiment runner ignore MaxIterWarning (the presets' budgets are fixed,
as the paper's): this process records them instead (``warnings.simplefilter`` told to ignore
MaxIterWarning records it), so that a run shows whether any fit or transfer stopped at its
``max_iter``: ``python with_warnings.py LOG bench which-learner ...`` (in this process only: ``--jobs 1``).
"""

import sys
import warnings

from factirl_opt.exceptions import MaxIterWarning
from factirl_opt.lab import cli

log_path, args = sys.argv[1], sys.argv[2:]
_simplefilter, _showwarning = warnings.simplefilter, warnings.showwarning


def simplefilter(action, category=Warning, *rest, **kw):
    if action == "ignore" and isinstance(category, type) and issubclass(category, MaxIterWarning):
        action = "always"
    return _simplefilter(action, category, *rest, **kw)


def showwarning(message, category, filename, lineno, file=None, line=None):
    if issubclass(category, MaxIterWarning):
        with open(log_path, "a") as log:
            log.write(f"{message}\n")
    else:
        _showwarning(message, category, filename, lineno, file, line)


warnings.simplefilter, warnings.showwarning = simplefilter, showwarning
open(log_path, "a").close()
sys.exit(cli.main(args))
