"""The ``factirl-opt`` command line: reproduce the paper's experiments, plot them, benchmark.

Examples
--------
::

    factirl-opt reproduce --preset quick --out runs/quick
    factirl-opt reproduce --preset paper --jobs 2 --out runs/paper
    factirl-opt plot runs/paper
    factirl-opt bench fit --help
"""

import argparse
import os
import shlex
import sys

from .exceptions import FactIRLError

__all__ = ["main", "build_parser"]

PROG = "factirl-opt"


def _positive_int(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {v}")
    return v


def _jobs(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v == 0 or v < -1:
        raise argparse.ArgumentTypeError(f"expected a positive integer or -1 (every core), got {v}")
    return v


def _seed(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {v}")
    return v


def build_parser():
    """The argument parser of ``factirl-opt`` (sub-commands reproduce, plot, bench)."""
    from .experiments.presets import PRESETS

    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Multi-task inverse reinforcement learning (Mangin & Oudeyer 2014): reproduce the paper's "
        "experiments, plot them, run the benchmarks.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    rep = sub.add_parser(
        "reproduce",
        help="run the paper's experiments (figures 1-3) and write tables and figures",
        description="Run every learner of the paper's section 4 on every point of a preset's two sweeps "
        "(demos per task; number of training tasks) for several seeds, then write results.csv, summary.csv, "
        "timings.csv, manifest.json and the figures into --out. Finished runs are saved one file each in "
        "OUT/runs, so rerunning the same command after an interruption computes only the missing runs.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    presets = "; ".join(f"{name}: {len(p.points())} points x {p.n_seeds} seed(s)" for name, p in PRESETS.items())
    rep.add_argument("--preset", default="quick", choices=list(PRESETS),
                     help=f"experiment configuration ({presets}); see factirl_opt.experiments.presets")
    rep.add_argument("--seed", type=_seed, default=0, metavar="BASE",
                     help="base seed: the runs use seeds BASE, BASE+1, ... (each run's streams are spawned from its seed)")
    rep.add_argument("--seeds", type=_positive_int, default=None, metavar="N",
                     help="number of seeds (default: the preset's)")
    rep.add_argument("--jobs", type=_jobs, default=1, metavar="N",
                     help="runs executed in parallel (joblib processes, or dask tasks); -1 uses every core. "
                     "Results do not depend on it")
    rep.add_argument("--out", default=None, metavar="DIR", help="output directory (default: runs/<preset>)")
    rep.add_argument("--h-solver", default="armijo", metavar="NAME",
                     help="H-step solver of the factorial learner (fit and transfer): any name in "
                     "solvers.available_solvers()")
    rep.add_argument("--backend", default="loky", choices=["loky", "dask"],
                     help="joblib backend: local processes (loky) or a Dask cluster (needs the 'dask' extra)")
    rep.add_argument("--scheduler", default=None, metavar="ADDRESS",
                     help="Dask scheduler address (e.g. tcp://host:8786) for --backend dask; without it a local "
                     "cluster of --jobs workers is started")
    rep.add_argument("--no-plot", action="store_true", help="write the tables only (plot later with `factirl-opt plot DIR`)")
    rep.add_argument("--quiet", action="store_true", help="no progress bar")
    rep.set_defaults(handler=_reproduce)

    plot = sub.add_parser(
        "plot",
        help="draw figures 1-3 (PNG and SVG) from a reproduce output directory",
        description="Read DIR/results.csv, DIR/figure3.json and DIR/manifest.json (written by `reproduce`) and "
        "write DIR/figures/figure{1,2,3}.{png,svg}.",
    )
    plot.add_argument("dir", metavar="DIR", help="output directory of `factirl-opt reproduce`")
    plot.set_defaults(handler=_plot)

    bench = sub.add_parser(
        "bench",
        help="run a benchmark (same as python -m factirl_opt.bench); `factirl-opt bench --help` lists them",
        add_help=False,
    )
    bench.add_argument("bench_args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    bench.set_defaults(handler=_bench)
    return parser


def _reproduce(args, argv):
    from .experiments.runner import run_sweep

    out = args.out or os.path.join("runs", args.preset)
    command = " ".join([PROG] + [shlex.quote(a) for a in argv])
    res = run_sweep(args.preset, out, seeds=args.seeds, base_seed=args.seed, jobs=args.jobs, h_solver=args.h_solver,
                    backend=args.backend, scheduler=args.scheduler, progress=not args.quiet, command=command)
    print(f"{res['n_runs']} runs ({res['n_computed']} computed, {res['n_runs'] - res['n_computed']} reused) "
          f"in {res['wall_time']:.1f} s")
    print(f"tables: {os.path.join(out, 'results.csv')}, {os.path.join(out, 'summary.csv')}")
    if not args.no_plot:
        _claims_and_figures(out)
    return 0


def _claims_and_figures(out):
    """Write ``out/claims.md`` and draw figures 1-3 from a reproduce directory."""
    from .experiments.claims import write_claims
    from .experiments.figures import plot_all
    from .experiments.tables import load_preset_from_manifest

    for path in plot_all(out):  # checks results.csv and the manifest first
        print(f"wrote: {path}")
    print(f"wrote: {write_claims(out, load_preset_from_manifest(out))}")


def _plot(args, argv):
    if not os.path.isdir(args.dir):
        raise FactIRLError(f"{args.dir!r} is not a directory; give the --out directory of `factirl-opt reproduce`")
    _claims_and_figures(args.dir)
    return 0


def _bench(args, argv):
    from .bench import main as bench_main

    return bench_main(args.bench_args, prog=f"{PROG} bench")


def main(argv=None):
    """Entry point of the ``factirl-opt`` console script; returns the exit code.

    Mistakes in the options give argparse's usage message; errors raised by the library on bad
    values (unknown solver, bad directory, ...) give a one-line message; both exit with code 2.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if argv[:1] == ["bench"]:  # everything after `bench` (--help included) belongs to the benchmark parser
        args = argparse.Namespace(handler=_bench, bench_args=argv[1:])
    else:
        args = parser.parse_args(argv)
    try:
        return args.handler(args, argv)
    except FactIRLError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{PROG}: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
