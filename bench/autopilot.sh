#!/usr/bin/env sh
# Autopilot emulator benchmark (issue 4): vehicles at 1x and speedup for 20 vehicles.
# Records go to docs/RESULTS.md with `nproc` and the CPU model. Usage: bench/autopilot.sh [--json]
set -eu
cd "$(dirname "$0")/.."
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')" >&2
exec python -m plmarl_sitl.cli bench autopilot "$@"
