#!/usr/bin/env bash
# Per-agent decision latency of the shipped policies (PL-MARL vs GRU-MARL, same run).
# Usage: bench/infer.sh [--json]
set -euo pipefail
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
exec python -m plmarl_sitl.cli bench infer "$@"
