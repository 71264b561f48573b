"""``bench active``'s runs with other request options and another draw of the demonstrations' randomness.

Usage: OMP_NUM_THREADS=1 python results/active/replicate.py WORLD SEED VARIANT [VARIANT ...]

WORLD: grid or objectworld-per-task-quick; each VARIANT is a strategy of ``bench active`` followed
by ``request_starts`` options, comma-separated (``requested,criterion=regret``,
``requested-value,demonstrated=skip``). The model and test tasks are ``bench active``'s; the
demonstrations' random transitions (and random starts) are drawn from the generator of the named
strategy (``[seed, index of the strategy]``), so ``requested,criterion=regret`` replays
``requested-regret`` with the demonstrations' randomness of ``requested``: a second draw of that
noise. Prints one JSON line per variant: the mean deviation over the test tasks after 1..8
demonstrations.
"""

import json
import sys

from factirl_opt.lab.benchmarks.active import DEFAULTS, strategy_run, world
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.learners.factirl import FactIRL


def main(name, seed, variants):
    s = dict(DEFAULTS)
    preset, gt, train_mdps, train_feats, mdps, feats = world(name, s, seed)
    n = min(s["n_test"], len(gt.test_demos))
    model = FactIRL(rng=seed, features=train_feats,
                    **factorial_options(preset, preset.solvers, "policy-matching", features=train_feats is not None))
    model.fit(train_mdps, gt.train_demos)
    for v in variants:
        strategy, *options = v.split(",")
        r = strategy_run(model, gt, preset, mdps, feats, n, strategy, s, seed, **dict(o.split("=") for o in options))
        print(json.dumps({"world": name, "seed": seed, "variant": v, "deviation": [round(x, 3) for x in r["deviation"]]}),
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3:])
