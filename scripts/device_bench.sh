#!/usr/bin/env bash
# The speed check for a lent GPU machine (no Rust toolchain there): prebuilt, stripped
# benchmark binaries run with a thread sweep and the GPU case, one table printed, in
# under 5 minutes.
#
#   scripts/device_bench.sh prepare   # here, with cargo: builds the release benchmarks,
#                                      # strips and gzips them into .bench/, and downloads
#                                      # the Vulkan loader packages into .gl/
#   scripts/device_bench.sh run       # there: carry [".bench", ".gl"], run from the
#                                      # repository root; prints the table
#
# What runs (each in one process, so its setup is paid once):
# - deblur: benches/deblur.rs's 10 MP RGB photo (3872 × 2592, HQS, the profile's
#   varying field) in rayon pools of each size of THREADS, then on the GPU, with each
#   run's per-stage breakdown (LENSBLUR_BENCH_SWEEP, LENSBLUR_BENCH_REPS);
# - batch: benches/batch.rs's batch of simulated RAW photos (BATCH_PHOTOS of BATCH_MP
#   megapixels, 8 of 24 by default) to DNGs, every core, BATCH_REPS timed batches (1)
#   on the CPU and then on the GPU, each in photos per minute, with one photo's stages
#   timed alone in the log;
# - kernels: benches/kernels.rs (every kernel of the 2400 × 1600 shot, 1152 kernels),
#   once per pool size through RAYON_NUM_THREADS (largest first, while the budget
#   lasts), criterion's quick mode;
# - the machine: lscpu's cores and threads, the adapter wgpu picks.
# A section that would run past the budget (BUDGET_S, 280 s) is skipped and says so.
set -u
cd "$(dirname "$0")/.." || exit 1
THREADS=${THREADS:-1,2,4,8,16}
BUDGET_S=${BUDGET_S:-280}
BENCHES=(deblur batch kernels)

prepare() {
    set -e
    mkdir -p .bench .gl
    for f in .bench/ .gl/; do
        grep -qxF "/$f" .git/info/exclude 2>/dev/null || echo "/$f" >>"$(git rev-parse --git-path info/exclude)"
    done
    local args=()
    for b in "${BENCHES[@]}"; do args+=(--bench "$b"); done
    cargo bench --no-run "${args[@]}" --message-format=json 2>/dev/null |
        python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and "bench" in m["target"]["kind"]:
        print(m["target"]["name"], m["executable"])
' | while read -r name exe; do
        strip -o ".bench/$name" "$exe"
        gzip -9f ".bench/$name"
        echo "prepared .bench/$name.gz ($(du -h ".bench/$name.gz" | cut -f1))"
    done
    local o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
    mkdir -p /tmp/amd64/partial
    apt-get "${o[@]}" update >/dev/null
    (cd .gl && apt-get "${o[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 >/dev/null)
    echo "prepared .gl/ ($(ls .gl | wc -l) packages); carry .bench and .gl"
    # What a run carries to the device travels with the working tree, 64 MiB in all.
    local carry tree
    carry=$(du -sb .bench .gl | awk '{s += $1} END {print s}')
    tree=$(git ls-files -z | xargs -0 du -cb 2>/dev/null | tail -1 | cut -f1)
    echo "carry: $((carry >> 20)) MiB of .bench and .gl, $((tree >> 20)) MiB of tracked files (64 MiB in all)"
    if [ $((carry + tree)) -gt $((64 << 20)) ]; then
        echo "too large to carry with the working tree" >&2
        exit 1
    fi
}

START=$(date +%s)
left() { echo $((BUDGET_S - ($(date +%s) - START))); }

run() {
    if ! ldconfig -p | grep -q libvulkan; then
        for f in .gl/*.deb; do dpkg -x "$f" /; done
        ldconfig
    fi
    if [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
        export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
        export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
    fi
    export WGPU_BACKEND=${WGPU_BACKEND:-vulkan}
    local bin=/tmp/lensblur-bench
    mkdir -p "$bin"
    for b in "${BENCHES[@]}"; do
        if [ -f ".bench/$b.gz" ]; then
            gunzip -c ".bench/$b.gz" >"$bin/$b" && chmod +x "$bin/$b"
        fi
    done
    local log=${OUT:-/tmp}/device_bench.log
    : >"$log"
    echo "machine: $(lscpu | grep -E '^(Model name|Socket|Core|Thread)' | tr -s ' ' | paste -sd';')" | tee -a "$log"
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null | sed 's/^/gpu: /' | tee -a "$log"
    local rows=()
    if [ -x "$bin/deblur" ]; then
        echo "== deblur sweep ($THREADS)" | tee -a "$log"
        # The breakdowns go to stderr, one line per case to stdout.
        LENSBLUR_BENCH_SWEEP=$THREADS LENSBLUR_BENCH_REPS=${REPS:-3} \
            timeout "$(left)" "$bin/deblur" --bench >"$log.deblur" 2>>"$log"
        cat "$log.deblur" | tee -a "$log"
        while read -r line; do rows+=("$line"); done <"$log.deblur"
    else
        rows+=("deblur: no prebuilt binary (.bench/deblur.gz)")
    fi
    if [ -x "$bin/batch" ] && [ "$(left)" -lt 60 ]; then
        rows+=("batch skipped=time")
    elif [ -x "$bin/batch" ]; then
        echo "== batch" | tee -a "$log"
        LENSBLUR_BENCH_REPS=${BATCH_REPS:-1} LENSBLUR_BENCH_BATCH_MP=${BATCH_MP:-24} \
            LENSBLUR_BENCH_BATCH_PHOTOS=${BATCH_PHOTOS:-8} \
            timeout "$(left)" "$bin/batch" --bench >"$log.batch" 2>>"$log"
        cat "$log.batch" | tee -a "$log"
        while read -r line; do rows+=("$line"); done <"$log.batch"
    else
        rows+=("batch: no prebuilt binary (.bench/batch.gz)")
    fi
    if [ -x "$bin/kernels" ]; then
        echo "== kernels" | tee -a "$log"
        # Largest pools first: one kernels run on 1 thread takes ~40 s there, and
        # criterion runs it at least twice (warm-up, then the sample).
        for t in $(echo "${THREADS//,/ }" | tr ' ' '\n' | sort -rn); do
            if [ "$(left)" -lt 90 ]; then
                rows+=("kernels_2400x1600 threads=$t skipped=time")
                continue
            fi
            local out
            out=$(RAYON_NUM_THREADS=$t timeout "$(left)" "$bin/kernels" --bench --quick \
                --noplot 2400x1600 2>>"$log" | tee -a "$log" | grep -E '^ *time:' | head -1)
            rows+=("kernels_2400x1600 threads=$t ${out:-no result}")
        done
    fi
    echo
    echo "| case | result |"
    echo "|---|---|"
    for r in "${rows[@]}"; do
        echo "| ${r%% *} | ${r#* } |"
    done
    echo
    echo "elapsed $(($(date +%s) - START)) s; log $log"
}

case "${1:-}" in
prepare) prepare ;;
run) run ;;
*)
    echo "usage: scripts/device_bench.sh prepare|run" >&2
    exit 2
    ;;
esac
