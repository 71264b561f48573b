#!/bin/sh
# The acceptance scenario, side by side with e87d706 (run from the worktree root; /work/wt-e87 = git worktree of e87d706).
# Alternates processes: e87d706's default call, this code's candidates, e87d706 again, this code's defaults again.
set -e
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
HERE=$PWD
OUT=results/defaults/walled_maps_seed${SEED:-0}.jsonl
E87=${E87:-/work/wt-e87}
(cd $E87 && PYTHONPATH=$E87 python $HERE/results/defaults/defaults_study.py walled-maps --seed ${SEED:-0} --label e87d706 --out $HERE/$OUT)
PYTHONPATH=$HERE python results/defaults/defaults_study.py walled-maps --seed ${SEED:-0} --label HEAD --out $OUT \
    --candidates defaults preset joint-2-early joint-2 joint-2-lbfgs joint lbfgs-alternating lbfgs-start paper
(cd $E87 && PYTHONPATH=$E87 python $HERE/results/defaults/defaults_study.py walled-maps --seed ${SEED:-0} --label e87d706 --n-test 0 --out $HERE/$OUT)
PYTHONPATH=$HERE python results/defaults/defaults_study.py walled-maps --seed ${SEED:-0} --label HEAD --n-test 0 --out $OUT \
    --candidates defaults preset joint-2-early joint-2 joint-2-lbfgs joint
