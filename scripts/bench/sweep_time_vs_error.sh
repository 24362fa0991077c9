#!/usr/bin/env bash
# The README's error-vs-time figure: square scene, m = 1 and 2, h and dt refined together.
# Writes results/sweep-square*/sweep.csv and error_vs_time.png (via `parefg sweep`).
set -euo pipefail
cd "$(dirname "$0")/../.."
mkdir -p results
.venv/bin/parefg sweep square --out results/sweep-time-vs-error \
    --vary discretization.degree=1,2 \
    --vary discretization.h=0.125,0.0625,0.03125 \
    --vary time.dt=0.05,0.025,0.0125
