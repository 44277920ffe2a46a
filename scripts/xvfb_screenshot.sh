#!/usr/bin/env bash
# Runs the studio in a real window under Xvfb on the demo session, waits until the demo
# session is made and loaded, takes a screenshot of the screen and exits.
#   scripts/xvfb_screenshot.sh [OUT.png]
# Env:
#   LENSBLUR_BIN       the binary (default: the debug build, built if missing)
#   KEEP_DEMO=1        reuse the cached demo (default: a fresh data dir, so the
#                      first-launch path, demo simulation included, is what runs)
#   LENSBLUR_AUTORUN   stages to run once the shots are loaded, e.g. "detect,kernels";
#                      frame times are logged while they run
#   BUSY_SECONDS       with LENSBLUR_AUTORUN: seconds to let the stages run before the
#                      screenshot (default: until the last stage ends, at most 10 min)
#   WAIT_FOR           a line of the log to wait for before the screenshot (default
#                      "studio: ready"); "studio: before/after shown" waits for the
#                      first launch's calibrated demo photo in the Deblur view
# The log (first-frame time, readiness, frame times) is printed at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-screenshots/xvfb_studio.png}
BIN=${LENSBLUR_BIN:-${CARGO_TARGET_DIR:-target}/debug/lensblur}
if [ ! -x "$BIN" ]; then
  cargo build --bin lensblur
fi
for tool in xvfb-run import; do
  command -v "$tool" >/dev/null || { echo "$tool not found (apt-get install xvfb xauth imagemagick)" >&2; exit 1; }
done
LOG=$(mktemp)
DATA=""
if [ -z "${KEEP_DEMO:-}" ]; then
  DATA=$(mktemp -d)
  export XDG_DATA_HOME=$DATA
fi
export LENSBLUR_FRAME_LOG=1 WGPU_BACKEND=${WGPU_BACKEND:-vulkan}
export BIN LOG OUT BUSY_SECONDS=${BUSY_SECONDS:-600} WAIT_FOR=${WAIT_FOR:-studio: ready}
status=0
xvfb-run -a -s "-screen 0 1400x900x24" bash -c '
  "$BIN" studio >"$LOG" 2>&1 &
  pid=$!
  ready=""
  for _ in $(seq 1 2400); do
    if grep -q "$WAIT_FOR" "$LOG"; then ready=1; break; fi
    kill -0 $pid 2>/dev/null || break
    sleep 0.25
  done
  if [ -n "$ready" ] && [ -n "${LENSBLUR_AUTORUN:-}" ]; then
    # Let the stages run until the last one has logged its frame times, or for
    # BUSY_SECONDS.
    last=${LENSBLUR_AUTORUN##*,}
    for _ in $(seq 1 $((BUSY_SECONDS * 4))); do
      grep -q "frame times while jobs ran (.*$last" "$LOG" && break
      kill -0 $pid 2>/dev/null || break
      sleep 0.25
    done
  fi
  sleep 1
  import -window root "$OUT"
  kill $pid 2>/dev/null || true
  wait $pid 2>/dev/null || true
  [ -n "$ready" ]
' || status=$?
cat "$LOG"
rm -f "$LOG"
[ -n "$DATA" ] && rm -rf "$DATA"
if [ "$status" -ne 0 ]; then
  echo "the studio did not get ready (see the log above)" >&2
  exit "$status"
fi
echo "screenshot: $OUT"
