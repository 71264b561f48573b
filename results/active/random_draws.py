"""How much the random baseline's curve depends on its draw of starts: the ``random`` strategy of
``bench active`` with other generators of its starts, the demonstrations' transitions still from
the common random numbers (``demonstration_rng``), the model, tasks and settings as in the table.

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/active/random_draws.py WORLD SEED DRAW...
(one JSON line per draw: the deviation after 1..8 demonstrations; draw d uses the generator
``default_rng([seed, 1000 + d])`` for the starts)
"""

import json
import sys

import numpy as np

from factirl_opt.lab.benchmarks.active import DEFAULTS, strategy_run, world
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.learners.factirl import FactIRL
from factirl_opt.parallel import limit_blas_threads


def main(name, seed, draws):
    s = dict(DEFAULTS)
    preset, gt, train_mdps, train_feats, mdps, feats = world(name, s, seed)
    n = min(s["n_test"], len(gt.test_demos))
    with limit_blas_threads(1):
        model = FactIRL(rng=seed, features=train_feats,
                        **factorial_options(preset, preset.solvers, "policy-matching", features=train_feats is not None))
        model.fit(train_mdps, gt.train_demos)
        for d in draws:
            r = strategy_run(model, gt, preset, mdps, feats, n, "random", s, seed,
                             start_rng=np.random.default_rng([seed, 1000 + d]))
            print(json.dumps({"world": name, "seed": seed, "draw": d,
                              "deviation": [round(x, 4) for x in r["deviation"]]}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), [int(d) for d in sys.argv[3:]])
