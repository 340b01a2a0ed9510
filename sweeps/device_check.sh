#!/usr/bin/env bash
# The device check: simulate throughput, crlb, one identify and the design's gradient, on the
# lent accelerator (if JAX finds one) and on the host's CPU, each written as JSON.
#
#   bash sweeps/device_check.sh [OUT_DIR]      # default: $OUT if set (a device run), else results/device_check
#
# Under 5 minutes on a GPU with the CPU's run beside it; with no accelerator the CPU run alone
# (the device run is skipped, and said so). armimp_bench.device measures; --repeats and
# --only pass through as DEVICE_CHECK_ARGS.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT_DIR="${1:-${OUT:-results/device_check}}"
mkdir -p "$OUT_DIR"
PY="${PYTHON:-python}"
ARGS="${DEVICE_CHECK_ARGS:-}"
check() {  # check NAME [ENV=VALUE ...]: one process of the check, its JSON to OUT_DIR/NAME.json
  local name="$1"; shift
  env PYTHONPATH="sweeps${PYTHONPATH:+:$PYTHONPATH}" "$@" "$PY" -c '
import sys, armimp_jax as aj
aj.runtime.configure()  # the first call compiles (or loads from the compilation cache)
from armimp_bench import device
args = sys.argv[2:]
repeats = int(args[args.index("--repeats") + 1]) if "--repeats" in args else 3
only = args[args.index("--only") + 1].split(",") if "--only" in args else None
device.run(sys.argv[1], repeats=repeats, only=only)
' "$OUT_DIR/$name.json" $ARGS
}
start=$(date +%s)
check cpu JAX_PLATFORMS=cpu  # the CPU's run beside the device's (DEVICE_CHECK_ARGS="--repeats 1" keeps it short)
if "$PY" -c 'import jax, sys; sys.exit(0 if jax.default_backend() != "cpu" else 1)' 2>/dev/null; then
  check device
else
  echo "device_check: no accelerator found: the CPU run only ($OUT_DIR/cpu.json)" >&2
fi
echo "device_check: done in $(( $(date +%s) - start )) s; wrote $(ls "$OUT_DIR"/*.json | tr '\n' ' ')"
