"""Profile one FactIRL fit of ``bench mce`` in CPU time (issue 30's profiles, results/mce-speed/README.md).

    PYTHONPATH=. python results/mce-speed/profile_fit.py mce 10 /tmp/mce.prof

Arguments: the objective (``mce`` or ``policy-matching``), the number of tasks, and where the
``pstats`` file goes; prints the counts and the top entries by own and by cumulative time.
"""

import cProfile
import pstats
import sys
import time

from factirl_opt.lab import bench
from factirl_opt._threads import limit_blas_threads
from factirl_opt.lab.benchmarks import mce as m

objective, n_tasks, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
settings = m.resolve_settings(bench.build_parser().parse_args(["mce", "--n-tasks", str(n_tasks)]), m.DEFAULTS, m.QUICK)
preset = m.benchmark_preset(settings)
with limit_blas_threads(1):
    gt = m.objectworld_per_task(preset, n_tasks, settings["n_demos"], settings["seed"])
    profiler = cProfile.Profile(time.process_time)
    profiler.enable()
    model, wall, cpu, planner = m.fit_once(preset, gt, objective, settings["seed"] + 1)
    profiler.disable()
entry = m.fit_entry(model, wall, planner, gt, preset)
print(objective, "wall", wall, "cpu", cpu, "evaluations", model.n_evaluations_, planner.counts(),
      "deviation", entry["mean_train_deviation"])
profiler.dump_stats(out)
stats = pstats.Stats(out)
stats.sort_stats("tottime").print_stats(25)
stats.sort_stats("cumulative").print_stats(40)
