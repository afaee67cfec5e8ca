#!/usr/bin/env bash
# One prepared run of every accelerator check, for a machine with CUDA (see README "Performance").
#
#   OUT=/some/folder bash benchmarks/device_check.sh
#
# Needs the demo's front-stage outputs (make demo first): resources/demo, results/keyframes,
# results/fit_head, results/targets. Writes to $OUT: stages.log (what ran where, the demo's Stage 1 +
# Stage 2 on $DEV (default cuda) with wall times), stage2.json and stage2_strands.npz (to evaluate
# against the CPU run), render.txt (benchmarks/render_bench.py on cuda), fit.json and prior.json (CPU vs cuda
# agreement; fit.txt also holds the CUDA test), parallel.log (eight Stage 2 runs of the demo sharing the
# device, with their wall time). Each step has its own time limit so one slow step cannot starve the
# others; the parallel runs get what is left of BUDGET seconds (default 540) since the start. S1SET /
# S2SET override the stages' settings (JSON) for a quick dry run on the CPU.
set -u
OUT=${OUT:?set OUT to a folder}
PY=${PY:-python3}
export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
mkdir -p "$OUT"

DEV=${DEV:-cuda}
BUDGET=${BUDGET:-540}
START=$(date +%s)
{ nvidia-smi -L; $PY -c "import sys, torch; print(sys.version.split()[0], 'torch', torch.__version__, torch.cuda.is_available())"; nproc; } >"$OUT/stages.log" 2>&1

SEQ="--root resources/demo --subject synth_0000 --seq HAIR --keyframes results/keyframes/synth_0000/HAIR/keyframes.json \
 --head results/fit_head/synth_0000/HAIR/head.npz --targets results/targets/synth_0000/HAIR --device $DEV --no-progress"
[ -n "${S1SET:-}" ] || S1SET={}
[ -n "${S2SET:-}" ] || S2SET={}
W=/tmp/v2h_device
rm -rf "$W"
{
  t0=$(date +%s.%N)
  timeout 120 $PY -m vid2haircut stage1 $SEQ --settings "$S1SET" --seed 0 --out $W/stage1 --prior-dir src/vid2haircut/data/prior/default
  t1=$(date +%s.%N)
  timeout 300 $PY -m vid2haircut stage2 $SEQ --settings "$S2SET" --seed 0 --out $W/stage2 --stage1-dir $W/stage1
  t2=$(date +%s.%N)
  awk -v a="$t0" -v b="$t1" -v c="$t2" 'BEGIN { printf "stage1_wall_s %.1f\nstage2_wall_s %.1f\n", b - a, c - b }'
} >>"$OUT/stages.log" 2>&1
cp $W/stage2/stage2.json "$OUT/" 2>/dev/null
cp $W/stage2/strands.npz "$OUT/stage2_strands.npz" 2>/dev/null

timeout 100 $PY benchmarks/render_bench.py --device $DEV --backend torch --repeat 3 >"$OUT/render.txt" 2>&1
timeout 40 $PY benchmarks/render_bench.py --device $DEV --backend torch --quick --frames 8 >>"$OUT/render.txt" 2>&1
timeout 100 $PY benchmarks/fit_device_check.py --out "$OUT/fit.json" >"$OUT/fit.txt" 2>&1
timeout 50 $PY benchmarks/prior_device_check.py --out "$OUT/prior.json" >>"$OUT/fit.txt" 2>&1
timeout 90 $PY -m pytest -q -p no:cacheprovider tests/test_render.py -k cuda >>"$OUT/fit.txt" 2>&1
PAR_S=$(( BUDGET - ($(date +%s) - START) - 15 ))
[ "$PAR_S" -ge 30 ] || PAR_S=30
{
  echo "parallel_timeout_s $PAR_S"
  t0=$(date +%s.%N)
  for s in 1 2 3 4 5 6 7 8; do
    timeout $PAR_S $PY -m vid2haircut stage2 $SEQ --settings "$S2SET" --seed $s --out $W/par$s --stage1-dir $W/stage1 \
      >$W/par$s.log 2>&1 &
  done
  wait
  t1=$(date +%s.%N)
  ok=$(ls $W/par*/stage2.json 2>/dev/null | wc -l)
  awk -v a="$t0" -v b="$t1" -v n="$ok" 'BEGIN { printf "parallel_stage2_runs_ok %d\nparallel_wall_s %.1f\nper_run_s %.1f\n", n, b - a, (b - a) / 8 }'
  tail -n 3 $W/par1.log
} >"$OUT/parallel.log" 2>&1
cat "$OUT/stages.log" "$OUT/render.txt" "$OUT/fit.txt" "$OUT/parallel.log"
