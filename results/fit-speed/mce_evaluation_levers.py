"""CPU of the pieces left in one MCE evaluation on a per-task Objectworld map (S = 576, A = 5).

One map of ``mce_evaluation.py``'s setting (the ``objectworld-per-task`` preset, 24x24, 30 walls,
seed 0), one task: the soft backup and its parts, the planner's backup and pullback against a
bare sparse product (bit for bit the same values), and a SuperLU factorisation of a random soft
policy's ``M^T`` with SuperLU's blocks memory-mapped (``mapped_allocations``, as the planner
does) or not (user and system CPU, minor page faults per factorisation).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/mce_evaluation_levers.py > out.json
"""

import dataclasses
import json
import resource
import time
import timeit
import warnings

import numpy as np
import scipy.sparse.linalg as spla

import factirl_opt as fo
from factirl_opt.lab.experiments.presets import get_preset
from factirl_opt.objectives import mce
from factirl_opt.planning import get_planner
from factirl_opt.planning import sparse_lu as slu

warnings.simplefilter("ignore")
preset = dataclasses.replace(get_preset("objectworld-per-task"), grid_size=24)
maps = fo.objectworld_maps(1, size=24, n_inner=preset.n_primitives, n_outer=preset.n_outer_colours,
                           object_density=preset.object_density, determinism=preset.p_success, gamma=preset.gamma,
                           n_blocked=30, rng=np.random.default_rng(0))
mdp = maps.mdps[0]
pl = get_planner(mdp, preset.planner)
rng = np.random.default_rng(1)
S, A, beta = mdp.n_states, mdp.n_actions, preset.beta
R, V, G = rng.normal(size=(1, S, A)), rng.normal(size=(1, S)), rng.normal(size=(1, S, A))


def us(f, number=2000):
    return round(min(timeit.repeat(f, number=number, repeat=3, timer=time.process_time)) / number * 1e6, 1)


Q = pl.q_from_values(R, V)
m = Q.max(axis=2)
z = beta * (Q - m[:, :, None])
out = dict(S=S, A=A, planner=type(pl).__name__, us_per_call=dict(
    soft_backup=us(lambda: mce.soft_backup(pl, R, V, beta)),
    q_from_values=us(lambda: pl.q_from_values(R, V)),
    backup=us(lambda: pl.backup(V)),
    bare_product_P_v=us(lambda: (pl.P @ V[0]).reshape(1, S, A)),
    pullback=us(lambda: pl.pullback(G)),
    bare_product_PT_g=us(lambda: (pl.PT @ G.reshape(S * A))[None]),
    exp_S_A=us(lambda: np.exp(z)),
))
out["bare_products_equal"] = bool(np.array_equal(pl.backup(V), (pl.P @ V[0]).reshape(1, S, A))
                                  and np.array_equal(pl.pullback(G), (pl.PT @ G.reshape(S * A))[None]))

MT = pl._stochastic_matrix_transpose(rng.dirichlet(np.ones(A), size=S))
out["nnz_M"] = int(MT.nnz)


def plain():
    return spla.splu(MT, permc_spec=pl.permc_spec, diag_pivot_thresh=0.0, options={"SymmetricMode": True})


lu_runs = []
for _ in range(2):
    for name, f in (("mapped", lambda: slu.lu(MT, pl.permc_spec)), ("plain", plain)):
        n = 500
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.process_time()
        for _ in range(n):
            f()
        t1, r1 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF)
        lu_runs.append(dict(allocation=name, cpu_us=round((t1 - t0) / n * 1e6, 1),
                            user_us=round((r1.ru_utime - r0.ru_utime) / n * 1e6, 1),
                            sys_us=round((r1.ru_stime - r0.ru_stime) / n * 1e6, 1),
                            minor_faults=round((r1.ru_minflt - r0.ru_minflt) / n, 1)))
out["lu_per_factorisation"] = lu_runs
print(json.dumps(out, indent=1))
