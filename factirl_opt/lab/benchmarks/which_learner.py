"""Which learner when: flat, factorial (fixed k) and the adaptive learner, side by side on every benchmark.

Runs the "which learner when" presets (:data:`factirl_opt.lab.experiments.presets.SHARING_PRESETS`:
the paper's grid at 5, 20 and 100 training tasks, ``objectworld-quick``,
``objectworld-per-task-quick``, BabyAI GoToLocal and GoToOpen), each with the experiment
runner into ``OUT/<preset>`` (resumable: finished runs are reused, as ``factirl-opt reproduce``
does; each directory gets its tables and ``claims.md``; runs of other seeds computed into the
same directories, e.g. by ``--seed 1 --seeds 2`` elsewhere and copied in, are reused), then compares, on the test tasks
(``transfer`` from ONE demonstration) of every point and seed, the adaptive learner
(``FactIRL(n_primitives="auto", residual_penalty="auto")``) with the better of the flat and the
factorial learner: *no worse* within 10% of the deviation, or 0.05 of the success rate on
BabyAI (:data:`factirl_opt.lab.experiments.claims.SHARING_MARGINS`); *beats both* when it is
better than both. Prints the comparison as JSON, with the (k, lambda) each adaptive fit chose and
the cost of ``"auto"`` (``auto_cost_ratio``: the median over runs of the adaptive training fit's
CPU time over the factorial one's, both from the same flat start; ``auto_cost_clock`` says
``"wall"`` where older run records hold wall time only), and writes it as a markdown table to ``OUT/which-learner.md``.

``--route NAME`` runs the adaptive learner with another search route
(:data:`factirl_opt.learners.selection.ROUTES`; the presets' ``sharing_route``): its runs have
keys of their own, so give them an ``--out`` of their own too.

``--quick`` runs the tiny grid only (``sharing-tiny``, one seed): seconds, for tests.
"""

import dataclasses
import os
import statistics

from ...files import write_text_atomic
from ..arguments import integer, text
from ..experiments.claims import SHARING_MARGINS, sharing_verdicts, write_claims
from ..experiments.presets import PRESETS, SHARING_PRESETS
from ..experiments.runner import run_sweep
from ...learners.selection import DEFAULT_ROUTE, ROUTES
from . import add_option, resolve_settings

__all__ = ["add_arguments", "benchmark_verdicts", "run", "sharing_table"]

DEFAULTS = {"presets": list(SHARING_PRESETS), "seed": 0, "seeds": 3, "jobs": 1, "out": os.path.join("runs", "which-learner"),
            "route": DEFAULT_ROUTE}
QUICK = {"presets": ["sharing-tiny"], "seeds": 1}
#: the file of the comparison in OUT
TABLE_FILE = "which-learner.md"


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--presets", choices=[*SHARING_PRESETS, "sharing-tiny"], nargs="+", metavar="PRESET",
        help=f"benchmarks to run, of {', '.join(SHARING_PRESETS)}, sharing-tiny")
    opt("--seed", type=integer(0), metavar="BASE", help="base seed: the runs use seeds BASE, BASE+1, ...")
    opt("--seeds", type=integer(1), metavar="N", help="seeds per benchmark")
    opt("--jobs", type=integer(1, also=(-1,)), help="runs executed in parallel (-1: every core); results do not depend on it")
    opt("--out", type=text("an output directory"), metavar="DIR",
        help="output directory: one reproduce directory per preset, and the table")
    opt("--route", choices=list(ROUTES), help="the search route of the adaptive learner")
    parser.add_argument("--quick", action="store_true",
                        help="the tiny grid only, one seed (for tests); options given explicitly keep their value")


def _column(rows):
    return "success_rate" if any(r.get("success_rate") is not None for r in rows) else "deviation"


def _chosen(rows):
    """``{(n_tasks, demos, seed): (k, lambda)}`` of the adaptive test rows (what the validation chose)."""
    return {(r["n_tasks"], r["demos_per_task"], r["seed"]): (r["n_primitives"], r["residual_penalty"])
            for r in rows if r["split"] == "test" and "n_primitives" in r}


def benchmark_verdicts(rows):
    """The verdicts of one benchmark's run rows (of any points and seeds, whatever code computed them).

    Parameters
    ----------
    rows : list of dict
        The rows of the benchmark's run records (``record["rows"]``), train and test.

    Returns
    -------
    dict
        ``column``: the score compared (``"success_rate"`` when the rows have one, else
        ``"deviation"``); ``verdicts``: one dict per point and seed,
        :func:`~factirl_opt.lab.experiments.claims.sharing_verdicts` on the test rows, with the
        ``n_primitives`` and ``residual_penalty`` the adaptive learner chose.
    """
    column = _column(rows)
    chosen = _chosen(rows)
    verdicts = [dict(v, n_primitives=chosen[key][0], residual_penalty=chosen[key][1])
                for v in sharing_verdicts(rows, "test", column)
                for key in [(v["n_tasks"], v["demos_per_task"], v["seed"])]]
    return {"column": column, "verdicts": verdicts}


def _lam(value):
    return "inf" if value == float("inf") else f"{value:g}"


def _cost(timings, rows):
    """Median over the runs of the adaptive training fit's time over the factorial one's (both from the
    same flat start, which neither includes): the cost of ``"auto"`` against one fixed fit, in CPU time
    (``fit_cpu_time``) where every run record has it, in wall time otherwise. Returns
    ``(ratio, "cpu" | "wall")``, ``(None, None)`` without a pair."""
    train = [t for t in timings if t["split"] == "train"]
    clock = "fit_cpu_time" if train and all("fit_cpu_time" in t for t in train) else "fit_time"
    times: dict = {}
    for t in train:
        times.setdefault((t["n_tasks"], t["demos_per_task"], t["seed"]), {})[t["learner"]] = t[clock]
    names = {r["learner"] for r in rows if "n_primitives" in r}
    fixed = {r["learner"] for r in rows if r["split"] == "train"} - names
    ratios = sorted(t[a] / t[f] for t in times.values() for a in names for f in fixed
                    if a in t and f in t and f.startswith("factorial") and t[f] > 0)
    if not ratios:
        return None, None
    return float(statistics.median(ratios)), ("cpu" if clock == "fit_cpu_time" else "wall")


def sharing_table(results: dict) -> str:
    """The markdown table of :func:`run`'s ``benchmarks``: one line per benchmark, point and seed."""
    lines = ["| benchmark | point | seed | score | flat | factorial | adaptive (k, lambda) | no worse | beats both |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, res in results.items():
        for v in res["verdicts"]:
            lines.append(f"| {name} | {v['n_tasks']} tasks x {v['demos_per_task']} demos | {v['seed']} | {res['column']} | "
                         f"{v['flat']:.3f} | {v['factorial']:.3f} | {v['adaptive']:.3f} "
                         f"({v['n_primitives']}, {_lam(v['residual_penalty'])}) | "
                         f"{'yes' if v['no_worse'] else '**no**'} | {'yes' if v['beats_both'] else 'no'} |")
    return "\n".join(lines) + "\n"


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    out = os.fspath(s["out"])
    results = {}
    route = f" --route {s['route']}" if s["route"] != DEFAULT_ROUTE else ""
    for name in s["presets"]:
        preset = dataclasses.replace(PRESETS[name], sharing_route=s["route"])
        res = run_sweep(preset, os.path.join(out, name), seeds=s["seeds"], base_seed=s["seed"], jobs=s["jobs"],
                        progress=True, command=f"factirl-opt bench which-learner --presets {name} --seed {s['seed']} "
                                               f"--seeds {s['seeds']} --out {out}{route}")
        write_claims(res["out"], preset)
        rows = res["rows"]
        judged = benchmark_verdicts(rows)
        column, verdicts = judged["column"], judged["verdicts"]
        results[name] = {"column": column, "margin": SHARING_MARGINS[column], "verdicts": verdicts,
                         "no_worse": f"{sum(v['no_worse'] for v in verdicts)}/{len(verdicts)}",
                         "beats_both": f"{sum(v['beats_both'] for v in verdicts)}/{len(verdicts)}",
                         **dict(zip(("auto_cost_ratio", "auto_cost_clock"), _cost(res["timings"], rows))),
                         "wall_time_s": res["wall_time"], "n_computed": res["n_computed"]}
    write_text_atomic(os.path.join(out, TABLE_FILE),
                      "# Which learner when: the adaptive learner against the better of flat and factorial\n\n"
                      "Test tasks, transfer from one demonstration. Score: deviation (lower is better; no worse: within "
                      f"{SHARING_MARGINS['deviation']:.0%} of the better) or success rate in the environment (higher is "
                      f"better; no worse: within {SHARING_MARGINS['success_rate']}).\n\n" + sharing_table(results))
    return {"settings": {k: v for k, v in s.items() if k != "quick"}, "benchmarks": results}
