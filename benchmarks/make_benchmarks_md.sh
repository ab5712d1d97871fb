#!/usr/bin/env bash
# Rebuild BENCHMARKS.md from benchmarks/summary.md (targets vs latest figures, written by hand after a run)
# and the sections each benchmark script writes to benchmarks/results/<component>.md.
set -euo pipefail
cd "$(dirname "$0")/.."
{
  cat benchmarks/summary.md
  for part in simulator recording perception tracker moving_camera heldout heldout_pre_blob_follow heldout_pre_region heldout_pre_refinement castle tracker_speed odometry odometry_in_tracker odometry_parts odometry_fused odometry_s9 odometry_s9_default odometry_s10 odometry_s16 odometry_fps heldout_odometry heldout_odometry_fused heldout_hands assembly hands hands_s33 hands_s32 hands_s31 hands_s30 hands_s29 hands_s28 hands_s27 hands_s26 hands_s25 hands_s24 hands_s21_s2 hands_s21_s13 hands_s20_s2 hands_s20_s13 hands_s18_s2 hands_s1 hands_particles hands_speed hand_gate batch server server_odometry server_hands_s34b server_hands_s34 server_hands_s33b server_hands_s33 server_hands_s32b server_hands_s31 server_hands_s30 server_hands_s29 server_hands_s28 server_hands_s27 server_hands_s26 server_hands_s24 server_hands_s24_hspeed server_hands_s10 server_hands_s11 server_hands_s18 server_hands_s22 server_hands_s20 server_hands_s19 soak soak_short; do
    if [ -f "benchmarks/results/$part.md" ]; then
      printf '\n'
      sed 's/^## /## /' "benchmarks/results/$part.md"
    fi
  done
} > BENCHMARKS.md
echo "wrote BENCHMARKS.md"
