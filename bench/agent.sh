#!/usr/bin/env bash
# Deployed agent in SITL (issue 5): decision-loop p50/p99, agent RSS and start-up time,
# N = 20 agents at speedup 10. Usage: bench/agent.sh [--json] [--n 20] [--speedup 10]
set -euo pipefail
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')" >&2
exec python -m plmarl_sitl.cli bench agent "$@"
