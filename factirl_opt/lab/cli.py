"""The ``factirl-opt`` command line: reproduce the paper's experiments, plot them, benchmark.

Examples
--------
::

    factirl-opt reproduce --preset quick --out runs/quick
    factirl-opt reproduce --preset paper --jobs 2 --out runs/paper
    factirl-opt reproduce --preset tiny --h-solver gn-qp-osqp-sparse --h-solver-options alpha=0.03
    factirl-opt reproduce --preset tiny --planner sparse-lu
    factirl-opt reproduce --preset paper --lineup paper+mce --jobs 2 --out runs/paper-mce
    factirl-opt plot runs/paper
    factirl-opt bench fit --help
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import signal
import sys
import textwrap
import warnings
from collections.abc import Sequence
from typing import Any

from ..validation import check_int
from ..exceptions import FactIRLError, ValidationError
from ..parallel import BACKENDS
from .arguments import mark_checked, scheduler_address

__all__ = ["main", "build_parser", "parse_solver_options"]

PROG = "factirl-opt"


def _integer(name, minimum, also=(), note=""):
    """An argparse type: an integer checked by the library's validator (``also``: extra allowed values)."""

    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer{note}; got {text!r}") from None
        if value in also:
            return value
        try:
            return check_int(value, name, minimum=minimum)
        except ValidationError as exc:
            raise argparse.ArgumentTypeError(f"{exc}{note}") from None

    return mark_checked(parse, f"an integer >= {minimum}")


def parse_solver_options(text: str) -> dict[str, Any]:
    """Solver options from the command line: a JSON object, or comma-separated ``key=value`` pairs.

    Values of the pairs are read as JSON when they parse (numbers, ``true``, ``null``, quoted
    strings) and as plain strings otherwise: ``alpha=0.03,interface=direct`` gives
    ``{"alpha": 0.03, "interface": "direct"}``. Whether the solver accepts them is checked
    before any run starts.
    """
    text = text.strip()
    if text.startswith("{"):
        try:
            value = json.loads(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(f"not a JSON object ({exc}): {text!r}") from None
        if not isinstance(value, dict):
            raise argparse.ArgumentTypeError(f"expected a JSON object; got {text!r}")
        return value
    options = {}
    for pair in text.split(","):
        key, sep, raw = pair.partition("=")
        key = key.strip()
        if not sep or not key or key in options:
            raise argparse.ArgumentTypeError(f"expected a JSON object or key=value pairs (distinct keys); got {text!r}")
        try:
            options[key] = json.loads(raw)
        except ValueError:
            options[key] = raw.strip()
    return options


def _presets_epilog():
    from .experiments.presets import PRESET_DESCRIPTIONS, PRESETS

    lines = ["presets (factirl_opt.lab.experiments.presets):"]
    for name, p in PRESETS.items():
        flat = p.flat_solver if p.flat_solver == p.flat_features_solver else f"{p.flat_solver}/{p.flat_features_solver}"
        h, d = p.solvers.h_solver, p.solvers.d_solver
        solvers = "" if (h, d, flat) == ("armijo", "", "armijo") else f" [solvers: flat {flat}, H {h}, D {d or 'armijo'}]"
        lines.append(f"  {name:6s} {len(p.points())} points x {p.n_seeds} seed(s): {PRESET_DESCRIPTIONS[name]}{solvers}")
    return "\n".join(lines)


def _add_reproduce(sub):
    from .experiments.learners import LINEUPS
    from .experiments.presets import PRESETS
    from ..planning import AUTO_DENSE_MAX_STATES, available_planners

    rep = sub.add_parser(
        "reproduce",
        help="run the paper's experiments (figures 1-3) and write tables and figures",
        description=textwrap.fill(
            "Run every learner of the paper's section 4 on every point of a preset's two sweeps (demos per task; "
            "number of training tasks) for several seeds, then write results.csv, summary.csv, timings.csv, "
            "manifest.json, claims.md and the figures into --out. Finished runs are saved one file each in OUT/runs, "
            "so rerunning the same command after an interruption computes only the missing runs (records edited, "
            "truncated or made by other code are reported and recomputed).", 79),
        epilog=_presets_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rep.add_argument("--preset", default="quick", choices=list(PRESETS), help="experiment configuration, see below (default: quick)")
    rep.add_argument("--seed", type=_integer("seed", 0), default=0, metavar="BASE",
                     help="base seed: the runs use seeds BASE, BASE+1, ... (default: 0)")
    rep.add_argument("--seeds", type=_integer("seeds", 1), default=None, metavar="N",
                     help="number of seeds (default: the preset's)")
    rep.add_argument("--jobs", type=_integer("jobs", 1, also=(-1,), note=" (or -1: every core)"), default=1, metavar="N",
                     help="runs executed in parallel (worker processes, or dask tasks); -1 uses every core; "
                     "results do not depend on it (default: 1)")
    rep.add_argument("--out", default=None, metavar="DIR", help="output directory (default: runs/PRESET)")
    rep.add_argument("--h-solver", default=None, metavar="NAME",
                     help="H-step solver of the factorial learner (fit and transfer): any name in "
                     "solvers.available_solvers() (default: the preset's, see below)")
    rep.add_argument("--h-solver-options", type=parse_solver_options, default=None, metavar="OPTS",
                     help="its options, as JSON ('{\"alpha\": 0.03}') or key=value pairs (alpha=0.03,interface=direct) "
                     "(default: none with --h-solver, else the preset's)")
    rep.add_argument("--d-solver", default=None, metavar="NAME",
                     help="D-step solver of the factorial learner, any name in solvers.available_solvers() "
                     "(default: the preset's, else FactIRL's)")
    rep.add_argument("--d-solver-options", type=parse_solver_options, default=None, metavar="OPTS",
                     help="its options, like --h-solver-options (default: none with --d-solver, else the preset's)")
    rep.add_argument("--planner", default=None, choices=available_planners(),
                     help="planning engine of every learner and score (factirl_opt.available_planners(); 'auto': "
                     f"dense up to {AUTO_DENSE_MAX_STATES} states, sparse LU above); a planner other than the preset's "
                     "changes the runs' keys (default: the preset's, auto)")
    rep.add_argument("--lineup", default=None, choices=list(LINEUPS),
                     help="learner line-up (factirl_opt.lab.experiments.learners; e.g. paper+mce adds the MCE learners); a "
                     "line-up other than the preset's changes the runs' keys (default: the preset's)")
    rep.add_argument("--flat-solver", default=None, metavar="NAME",
                     help="step solver of every GradIRL fit (the flat learners, tabular and on features), any name in "
                     "solvers.available_solvers(); "
                     "a solver other than the preset's changes the runs' keys (default: the preset's)")
    rep.add_argument("--backend", default="processes", choices=[*BACKENDS, "loky"],
                     help="local worker processes, or a Dask cluster (needs the 'dask' extra); 'loky' is the former "
                     "name of 'processes' (default: processes)")
    rep.add_argument("--scheduler", type=scheduler_address, default=None, metavar="ADDRESS",
                     help="Dask scheduler address (e.g. tcp://host:8786) for --backend dask (default: a local "
                     "cluster of --jobs workers)")
    rep.add_argument("--no-plot", action="store_true",
                     help="write the tables only (plot later with `factirl-opt plot DIR`); claims.md and figures drawn "
                     "from earlier tables in DIR are removed either way, so they never sit beside other tables")
    rep.add_argument("--quiet", action="store_true", help="no progress bar")
    rep.set_defaults(handler=_reproduce)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``factirl-opt`` (sub-commands reproduce, plot, bench)."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Multi-task inverse reinforcement learning (Mangin & Oudeyer 2014): reproduce the paper's "
        "experiments, plot them, run the benchmarks.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_reproduce(sub)
    plot = sub.add_parser(
        "plot",
        help="draw figures 1-3 (PNG and SVG) and claims.md from a reproduce output directory",
        description="Read DIR/results.csv, DIR/figure3.json and DIR/manifest.json (written by `reproduce`) and "
        "write DIR/figures/figure{1,2,3}.{png,svg} and DIR/claims.md.",
    )
    plot.add_argument("dir", metavar="DIR", help="output directory of `factirl-opt reproduce`")
    plot.set_defaults(handler=_plot)
    bench = sub.add_parser(
        "bench",
        help="run a benchmark (same as python -m factirl_opt.lab.bench); `factirl-opt bench --help` lists them",
        add_help=False,
    )
    bench.add_argument("bench_args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    bench.set_defaults(handler=_bench)
    return parser


def _preset(args):
    """The preset named on the command line, with the options that override its fields."""
    from .experiments.presets import get_preset

    preset = get_preset(args.preset)
    overrides = {f: getattr(args, f) for f in ("planner", "lineup") if getattr(args, f) is not None}
    if args.flat_solver is not None:
        overrides.update(flat_solver=args.flat_solver, flat_features_solver=args.flat_solver)
    return dataclasses.replace(preset, **overrides) if overrides else preset


def _plan(args, preset):
    """The planned runs: the preset's points x the seeds, with the preset's solvers and the options' overrides."""
    from .experiments.runner import plan_sweep

    solvers = preset.solvers.with_overrides(args.h_solver, args.h_solver_options, args.d_solver, args.d_solver_options)
    n_seeds = preset.n_seeds if args.seeds is None else args.seeds
    return plan_sweep(preset, range(args.seed, args.seed + n_seeds), solvers)


def _reproduce(args, argv):
    """command line -> preset -> planned runs -> execution, store, tables -> claims and figures."""
    from .experiments.runner import Execution, SolverSubstitutionWarning, run_plan
    from .experiments.store import RejectedRunWarning

    if args.out is not None and not args.out.strip():
        raise ValidationError("--out is empty; give an output directory, or leave --out out for runs/PRESET")
    out = args.out or os.path.join("runs", args.preset)
    plan = _plan(args, _preset(args))
    execution = Execution(args.jobs, args.backend, args.scheduler)
    for note in plan.substitutions:
        print(f"{PROG}: warning: {note}", file=sys.stderr)
    command = " ".join([PROG] + [shlex.quote(a) for a in argv])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RejectedRunWarning)  # reported below, one line per record
        warnings.simplefilter("ignore", SolverSubstitutionWarning)  # reported above
        res = run_plan(plan, out, execution, progress=not args.quiet, command=command)
    if res["rejected"]:
        print(f"{PROG}: warning: rejected {len(res['rejected'])} run record(s), recomputed:", file=sys.stderr)
        for name, reason in sorted(res["rejected"].items()):
            print(f"  {name}: {reason}", file=sys.stderr)
    print(f"{res['n_runs']} runs ({res['n_computed']} computed, {res['n_runs'] - res['n_computed']} reused) "
          f"in {res['wall_time']:.1f} s")
    print(f"tables: {os.path.join(out, 'results.csv')}, {os.path.join(out, 'summary.csv')}")
    if not args.no_plot:
        _claims_and_figures(out)
    return 0


def _claims_and_figures(out: str) -> None:
    """Draw figures 1-3 and write ``out/claims.md`` from a reproduce directory."""
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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``factirl-opt`` console script; returns the exit code.

    Mistakes in the options give argparse's usage message; errors raised by the library on bad
    values (unknown solver, bad directory, a directory locked by another sweep...) give a
    one-line message; both exit with code 2. An interrupted sweep (Ctrl-C, SIGTERM) exits with
    128 + the signal number after stopping its workers; rerunning the command resumes it.
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
    except KeyboardInterrupt as exc:
        print(f"{PROG}: interrupted; rerun the same command to resume", file=sys.stderr)
        return 128 + interrupt_signal(exc)


def interrupt_signal(exc: BaseException) -> int:
    """The signal that caused the interrupt ``exc``: 2 (SIGINT) unless a SIGTERM is found.

    A fit interrupted in this process keeps its best point and raises its own
    ``FitInterrupted`` in place of the ``Terminated`` that SIGTERM raised, chained as its
    cause or context: the chain is searched for the ``signum`` of the original.
    """
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        signum = getattr(current, "signum", None)
        if isinstance(signum, int):
            return signum
        current = current.__cause__ or current.__context__
    return int(signal.SIGINT)


if __name__ == "__main__":
    sys.exit(main())
