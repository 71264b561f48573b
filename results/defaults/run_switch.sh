#!/bin/sh
# The acceptance draw after the switch, side by side with e87d706 (E87 = a git worktree of e87d706): for
# each seed, e87d706's default call, then this code's defaults and the joint scheme from the paper's flat
# start (joint-armijo-start), 100 test tasks; appends to results/defaults/walled_maps_switch_seedS.jsonl.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
HERE=$PWD
E87=${E87:-/tmp/wt-e87}
for S in ${SEEDS:-0 1 2}; do
  OUT=results/defaults/walled_maps_switch_seed$S.jsonl
  (cd $E87 && PYTHONPATH=$E87 python $HERE/results/defaults/defaults_study.py walled-maps --seed $S --n-test 100 --label e87d706 --out $HERE/$OUT)
  PYTHONPATH=$HERE python results/defaults/defaults_study.py walled-maps --seed $S --n-test 100 --label HEAD --out $OUT \
      --candidates ${C:-defaults joint-armijo-start}
done
