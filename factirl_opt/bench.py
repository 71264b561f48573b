"""Benchmark entry point: ``python -m factirl_opt.bench {gradient,fit,solvers} [options]``.

Every benchmark measures its routes side by side in one run and prints JSON on stdout.
"""

import argparse
import importlib
import json
import sys

from .benchmarks import BENCHMARKS

__all__ = ["main", "build_parser"]


def build_parser(parser=None):
    parser = parser or argparse.ArgumentParser(prog="python -m factirl_opt.bench", description=__doc__)
    sub = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    for name, module in BENCHMARKS.items():
        mod = importlib.import_module(f"factirl_opt.benchmarks.{module}")
        p = sub.add_parser(name, help=(mod.__doc__ or "").strip().splitlines()[0], description=mod.__doc__)
        mod.add_arguments(p)
        p.set_defaults(_module=mod)
    return parser


def run_from_args(args):
    result = args._module.run(args)
    json.dump(result, sys.stdout, indent=2, default=float)
    sys.stdout.write("\n")
    return result


def main(argv=None):
    args = build_parser().parse_args(argv)
    run_from_args(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
