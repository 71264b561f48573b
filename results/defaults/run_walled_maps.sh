#!/bin/sh
# The acceptance scenario, side by side with e87d706 (run from the worktree root; E87 = a git worktree of
# e87d706, /work/wt-e87 by default): e87d706's default call, then this code's candidates C, in alternating
# processes, seed SEED, NTEST test tasks, this code's rows labelled LABEL (default HEAD); appends to results/defaults/walled_maps_NTESTtest_seedSEED.jsonl.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
HERE=$PWD
S=${SEED:-0}; N=${NTEST:-100}
OUT=results/defaults/walled_maps_${N}test_seed$S.jsonl
E87=${E87:-/work/wt-e87}
C=${C:-defaults joint-lbfgs joint-2-lbfgs joint-2-lbfgs-early joint joint-2 joint-2-early preset}
LABEL=${LABEL:-HEAD}
(cd $E87 && PYTHONPATH=$E87 python $HERE/results/defaults/defaults_study.py walled-maps --seed $S --n-test $N --label e87d706 --out $HERE/$OUT)
PYTHONPATH=$HERE python results/defaults/defaults_study.py walled-maps --seed $S --n-test $N --label $LABEL --out $OUT --candidates $C
