"""Benchmarks: each module exposes ``add_arguments(parser)`` and ``run(args) -> dict``.

Run them with ``python -m factirl_opt.lab.bench NAME`` (or ``factirl-opt bench NAME``); each prints
its measurements as JSON. Their command line is built in one place, :func:`factirl_opt.lab.bench.build_parser`.

A benchmark with a ``--quick`` configuration declares its options with :func:`add_option` and
reads them with :func:`resolve_settings`: an option given on the command line wins, then the
``--quick`` value, then the default (so ``--quick --n-tasks 20`` runs 20 tasks).
"""

__all__ = ["BENCHMARKS", "add_option", "resolve_settings"]

#: benchmark name -> module under factirl_opt.lab.benchmarks
BENCHMARKS = {
    "gradient": "gradient",
    "fit": "fit",
    "solvers": "solvers",
    "scale": "scale",
    "environments": "environments",
    "robustness": "robustness",
    "unlabeled": "unlabeled",
    "mce": "mce",
    "dictionary": "dictionary",
    "auto-cost": "auto_cost",
    "which-learner": "which_learner",
    "active": "active",
    "gpi": "gpi",
}


def add_option(parser, *flags, defaults, quick=None, help="", **kwargs):
    """Add an option whose default is resolved later by :func:`resolve_settings`.

    The option's argparse default is None (so an explicit value can be told apart); its help
    shows ``defaults[dest]`` and, if any, ``quick[dest]``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    *flags : str
        E.g. ``"--n-tasks"``.
    defaults, quick : dict
        ``dest -> value`` without and with ``--quick``.
    help : str
    **kwargs
        Passed to ``parser.add_argument`` (``type``, ``nargs``, ``choices``...).
    """
    action = parser.add_argument(*flags, default=None, **kwargs)
    default = defaults[action.dest]
    shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else default
    text = f"default: {shown}"
    if quick and action.dest in quick:
        q = quick[action.dest]
        text += "; --quick: " + (" ".join(map(str, q)) if isinstance(q, (list, tuple)) else str(q))
    action.help = f"{help} ({text})" if help else f"({text})"
    return action


def resolve_settings(args, defaults, quick=None):
    """The settings of a run: explicit options > ``--quick`` values > defaults.

    Returns
    -------
    dict
        Every option of ``args`` (private ``_`` names excluded), with None replaced.
    """
    s = {k: v for k, v in vars(args).items() if not k.startswith("_")}
    for key, default in defaults.items():
        if s.get(key) is None:
            s[key] = quick[key] if s.get("quick") and quick and key in quick else default
    return s
