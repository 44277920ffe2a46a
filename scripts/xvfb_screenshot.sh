#!/usr/bin/env bash
# Runs the studio in a real window under Xvfb on the demo session, waits until the demo
# session is made and loaded, takes a screenshot of the screen and exits.
#   scripts/xvfb_screenshot.sh [OUT.png]
# Env: LENSBLUR_BIN (default: the debug build), KEEP_DEMO=1 to reuse the cached demo
# (default: a fresh data dir, so the first-launch path is what runs), LENSBLUR_AUTORUN
# (e.g. "detect,kernels": run stages after loading and log frame times meanwhile).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-screenshots/xvfb_studio.png}
BIN=${LENSBLUR_BIN:-${CARGO_TARGET_DIR:-target}/debug/lensblur}
if [ ! -x "$BIN" ]; then
  cargo build --bin lensblur
fi
LOG=$(mktemp)
if [ -z "${KEEP_DEMO:-}" ]; then
  export XDG_DATA_HOME=$(mktemp -d)
fi
export LENSBLUR_FRAME_LOG=1 WGPU_BACKEND=${WGPU_BACKEND:-vulkan}
export BIN LOG OUT
xvfb-run -a -s "-screen 0 1400x900x24" bash -c '
  "$BIN" studio >"$LOG" 2>&1 &
  pid=$!
  for _ in $(seq 1 1200); do
    grep -q "studio: ready" "$LOG" && break
    kill -0 $pid 2>/dev/null || break
    sleep 0.25
  done
  if [ -n "${LENSBLUR_AUTORUN:-}" ]; then
    # Let the autorun stages run until the last one has logged its frame times (at
    # most 10 minutes).
    last=${LENSBLUR_AUTORUN##*,}
    for _ in $(seq 1 2400); do
      grep -q "frame times while jobs ran (.*$last" "$LOG" && break
      kill -0 $pid 2>/dev/null || break
      sleep 0.25
    done
  fi
  sleep 1
  import -window root "$OUT"
  kill $pid 2>/dev/null || true
  wait $pid 2>/dev/null || true
'
cat "$LOG"
echo "screenshot: $OUT"
