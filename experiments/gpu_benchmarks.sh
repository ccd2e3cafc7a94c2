#!/usr/bin/env bash
# The open GPU measurements, in the order they matter, each writing its results file as its rows
# finish (a run cut short keeps what it measured). On one H100/H200 through the device tool:
#
#   bash experiments/gpu_benchmarks.sh ladder OUT     # ~5 min: lab li2020 at 4,096 robots, the
#                                                     # chunks-by-need ladder of factor 4
#                                                     # against 4 and 16 only (coarse_ladder):
#                                                     # 1.32x on a CPU, no gain on an H100 at
#                                                     # 1,024 robots and 12-18 s more compile
#                                                     # (2026-11-27): take it back if 4,096
#                                                     # gains nothing either
#   bash experiments/gpu_benchmarks.sh table OUT EB   # ~9-10 min: the README table (EB: a folder
#                                                     # holding room.yaml and room.pgm); its
#                                                     # office and room rows predate the
#                                                     # whole-grid belief update (lab's rows were
#                                                     # rerun 2026-11-27, bench_lab_li2020_gpu.md;
#                                                     # its compile is 43-74 s a batch size)
#   bash experiments/gpu_benchmarks.sh li2020 OUT     # ~7 min (never run yet): after its first
#                                                     # plans li2020 runs 9-10x the CPU at 4,096
#                                                     # robots, 4x at 1,024; where a plan's time
#                                                     # goes on a GPU, part by part, and the candidate
#                                                     # visible gains a depth at a time (185
#                                                     # loop steps, not ~1,950) alone and in
#                                                     # whole runs on lab (64 robots; the
#                                                     # lab part runs it at 256)
#   bash experiments/gpu_benchmarks.sh variants OUT   # ~4 min: office 1,024 / 4,096 robots, the
#                                                     # landed whole-grid update undone, and
#                                                     # the whole-grid leftovers by need undone
#                                                     # (fixed_leftovers: within the drift at
#                                                     # 4,096 on an H100), against head
#   bash experiments/gpu_benchmarks.sh lab OUT        # ~7 min: lab li2020 64 / 256, the landed
#                                                     # changes undone, visible_by_depth (and
#                                                     # visible, the region it is compared with)
#   bash experiments/gpu_benchmarks.sh stages OUT     # ~4 min: stage times, lockstep
#   bash experiments/gpu_benchmarks.sh slam OUT       # ~6 min (never run yet): scan_matching
#                                                     # against oracle, nearest frontier on
#                                                     # office, 1,024 and 4,096 robots (the SLAM
#                                                     # issue's GPU row; 0.32-0.35x on this CPU)
#
# OUT defaults to experiments/results. Each part is a few command lines below; run them by hand
# with other batch sizes as the budget allows.
set -euo pipefail
part=${1:?"which part: table, ladder, variants, li2020, lab, stages or slam"}
out=${2:-experiments/results}
mkdir -p "$out"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
case "$part" in
  ladder)
    python experiments/bench_lockstep_variants.py --setting lab --robots 4096 --steps 32 \
      --chunk-steps 16 --variants coarse_ladder --out "$out/bench_lockstep_ladder_gpu.md" ;;
  variants)
    python experiments/bench_lockstep_variants.py --setting office --robots 1024,4096 \
      --out "$out/bench_lockstep_variants_gpu.md" ;;
  li2020)
    python experiments/bench_li2020_parts.py --chunks 1,4,16,64 \
      --out "$out/bench_li2020_parts_gpu.md"
    python experiments/bench_visible_blocks.py --blocks 8 --by-depth 32 64 128 --robots 4 64 \
      --out "$out/bench_visible_blocks_gpu.md"
    python experiments/bench_lockstep_variants.py --setting lab --robots 64 --steps 32 \
      --chunk-steps 16 --variants visible,visible_by_depth \
      --out "$out/bench_lockstep_variants_lab_gpu.md"
    ;;
  lab)
    python experiments/bench_lockstep_variants.py --setting lab --robots 64,256 --steps 32 \
      --chunk-steps 16 --variants fixed_chunks,tile_loop,visible,visible_by_depth \
      --out "$out/bench_lockstep_variants_lab_gpu.md" ;;
  stages)
    python experiments/stage_times.py --settings office,lab --strategies lockstep \
      --robots 4,64,1024 --out "$out/stage_times_gpu.md" ;;
  table)
    eb=${3:?"a folder holding the Explore-Bench room.yaml and room.pgm"}
    python experiments/bench_accelerator.py --settings office --strategies lockstep \
      --robots 64,1024,4096,16384 --steps 96 --budget-s 30 --out "$out/bench_office_gpu.md"
    python experiments/bench_accelerator.py --settings eb:room --strategies lockstep \
      --robots 64,1024,4096 --steps 96 --budget-s 25 --explore-bench "$eb" \
      --out "$out/bench_room_gpu.md"
    python experiments/bench_accelerator.py --settings lab --strategies lockstep \
      --robots 64,256,1024,4096 --steps 32 --chunk-steps 16 --budget-s 60 \
      --out "$out/bench_lab_gpu.md" ;;
  slam)
    python experiments/bench_slam.py --worlds office --robots 1024,4096 --steps 128 \
      --out "$out/bench_slam_gpu.md" ;;
  *)
    echo "unknown part $part: table, ladder, variants, li2020, lab, stages or slam" >&2; exit 2 ;;
esac
