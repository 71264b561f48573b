"""Benchmarks: each module exposes ``add_arguments(parser)`` and ``run(args) -> dict``.

Run them with ``python -m factirl_opt.bench NAME`` (or ``factirl-opt bench NAME``); each prints
its measurements as JSON.
"""

#: benchmark name -> module under factirl_opt.benchmarks
BENCHMARKS = {
    "gradient": "gradient",
    "fit": "fit",
    "solvers": "solvers",
}
