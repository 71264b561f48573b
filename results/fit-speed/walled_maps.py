"""The draw that ``per_task_maps.py`` and ``mce_evaluation.py`` share: ``--n-tasks`` tasks, each on
its own ``--size`` x ``--size`` Objectworld map with ``--n-blocked`` blocked cells (walls),
``--n-demos`` demonstrations of ``--length`` steps, the ``objectworld-per-task`` preset's colours,
density, dynamics and discount. Written to run unchanged on older code (commit cf6a37f: the
harness in ``factirl_opt.experiments``)."""

import dataclasses
import warnings

import numpy as np

import factirl_opt as fo

try:
    from factirl_opt.lab.experiments.presets import get_preset
except ImportError:  # older code: the harness in factirl_opt.experiments
    from factirl_opt.experiments.presets import get_preset

with warnings.catch_warnings():  # the top-level aliases are deprecated on newer code
    warnings.simplefilter("ignore")
    objectworld_maps, state_action_rewards = fo.objectworld_maps, fo.state_action_rewards


def add_arguments(parser):
    """The draw's command-line options (and ``--seed``, ``--label``)."""
    parser.add_argument("--size", type=int, default=24)
    parser.add_argument("--n-tasks", type=int, default=16)
    parser.add_argument("--n-demos", type=int, default=24)
    parser.add_argument("--length", type=int, default=16)
    parser.add_argument("--n-blocked", type=int, default=30, help="blocked cells (walls) per map")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--label", default="")


def draw(args):
    """``(preset, maps, mdps, R, demos)``: the preset with the draw's size and length, the maps, one
    MDP per task, the true rewards (n, S, A) and the demonstrations."""
    preset = dataclasses.replace(get_preset("objectworld-per-task"), grid_size=args.size, demo_length=args.length)
    maps = objectworld_maps(args.n_tasks, size=args.size, n_inner=preset.n_primitives, n_outer=preset.n_outer_colours,
                            object_density=preset.object_density, determinism=preset.p_success, gamma=preset.gamma,
                            n_blocked=args.n_blocked, rng=np.random.default_rng(args.seed))
    mdps = list(maps.mdps)
    R = state_action_rewards(maps.rewards, mdps[0].n_actions)
    demos = fo.sample_demonstrations(mdps, R, args.n_demos, args.length, rng=np.random.default_rng(args.seed + 100),
                                     planner=preset.planner)
    return preset, maps, mdps, R, demos
