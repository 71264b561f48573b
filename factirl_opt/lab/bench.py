"""Benchmark entry point: ``python -m factirl_opt.lab.bench {gradient,fit,solvers,scale,environments,robustness,unlabeled,mce,dictionary,auto-cost,which-learner,active,gpi} [options]``.

Every benchmark measures its routes side by side in one run and prints JSON on stdout. The
same parser serves ``factirl-opt bench``.
"""

import argparse
import importlib
import json
import sys
import warnings

from .benchmarks import BENCHMARKS
from ..exceptions import FactIRLError, MaxIterWarning

__all__ = ["main", "build_parser", "run_from_args"]


def build_parser(prog="python -m factirl_opt.lab.bench"):
    """The benchmarks' argument parser: one sub-command per benchmark module.

    A benchmark whose module cannot be imported (a missing optional dependency) is listed as
    unavailable in the help instead of breaking the others.
    """
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0] + " Each prints JSON on stdout.")
    sub = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    missing = []
    for name, module in BENCHMARKS.items():
        try:
            mod = importlib.import_module(f"factirl_opt.lab.benchmarks.{module}")
        except ImportError as exc:
            missing.append(f"{name} ({exc})")
            continue
        p = sub.add_parser(name, help=(mod.__doc__ or name).strip().splitlines()[0], description=mod.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    if missing:
        parser.epilog = "unavailable: " + "; ".join(missing)
    return parser


def run_from_args(args):
    """Run the parsed benchmark and print its result as JSON on stdout; returns the result.

    The benchmarks run fixed budgets: the :class:`~factirl_opt.exceptions.MaxIterWarning` of
    their fits is ignored (the results record each fit's status)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MaxIterWarning)
        result = args._module.run(args)
    json.dump(result, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")
    return result


def main(argv=None, prog="python -m factirl_opt.lab.bench"):
    """Parse ``argv``, run the benchmark, print its JSON; returns the exit code.

    Every option is checked by the parser (its type or choices: a bad value is a usage
    error); a value the library refuses once the benchmark starts (a combination of options
    it cannot run) gives a one-line ``PROG: error: ...``. Both exit with code 2.
    """
    args = build_parser(prog).parse_args(argv)
    try:
        run_from_args(args)
    except FactIRLError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
