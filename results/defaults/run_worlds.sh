#!/bin/sh
# One seed (SEED, default 0) of the other benchmark worlds (WORLDS), the candidates C, one process
# per world (run from the worktree root), labelled LABEL (default HEAD). Each world appends to its own JSON-lines file.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
S=${SEED:-0}
C=${C:-defaults joint-2-lbfgs-early joint-2-lbfgs joint-lbfgs preset}
L=${LABEL:-HEAD}
run() { PYTHONPATH=$PWD python results/defaults/defaults_study.py "$@" --seed $S --label $L --candidates $C; }
for w in ${WORLDS:-grid-20 grid-100x2 grid-100x10 objectworld babyai}; do
  case $w in
    grid-20) run grid --n-tasks 20 --n-demos 10 --out results/defaults/grid_20x10_seed$S.jsonl ;;
    grid-100x2) run grid --n-tasks 100 --n-demos 2 --out results/defaults/grid_100x2_seed$S.jsonl ;;
    grid-100x10) run grid --n-tasks 100 --n-demos 10 --out results/defaults/grid_100x10_seed$S.jsonl ;;
    objectworld) run objectworld --n-tasks 20 --n-demos 32 --n-test 50 --out results/defaults/objectworld_20_seed$S.jsonl ;;
    babyai) run babyai --n-tasks 30 --n-demos 4 --n-test 100 --out results/defaults/babyai_30_seed$S.jsonl ;;
  esac
done
