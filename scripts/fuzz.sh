#!/usr/bin/env bash
# Coverage-guided fuzzing of lensblur's readers with AFL++ on stable Rust (cargo-afl).
#
#   scripts/fuzz.sh SECONDS [TARGET...]     each target for SECONDS or 10^6 inputs,
#                                           whichever comes first
#
# The seed corpora (fuzz/seeds/, files lensblur wrote) are made by
#   cargo run --example fuzz_seeds -- fuzz/seeds
#
# Targets: dng load exif chart manifest kernels detect profile session (all when none
# is named). A hang is an input over 1 s; memory is limited to 4 GiB per input (the
# largest image lensblur accepts needs under 2). Crashes and hangs land in
# fuzz/out/TARGET/default/{crashes,hangs}; copy each into fuzz/regressions/TARGET/
# once fixed: the test suite runs every file there. A summary line per target is
# printed at the end, with the inputs run.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
command -v cargo-afl >/dev/null || cargo install cargo-afl --locked
# Without `--cfg fuzzing`: under it the AV1 encoder inside `image` links libFuzzer,
# whose coverage hooks clash with AFL++'s.
AFL_NO_CFG_FUZZING=1 cargo afl build --release
seconds=${1:?usage: scripts/fuzz.sh SECONDS [TARGET...]}
shift
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(dng load exif chart manifest kernels detect profile session)
export AFL_NO_UI=1 AFL_SKIP_CPUFREQ=1 AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES=1 AFL_QUIET=1
for t in "${targets[@]}"; do
    rm -rf "out/$t"
    cargo afl fuzz -i "seeds/$t" -o "out/$t" -t 1000 -m 4096 -V "$seconds" -E 1000000 \
        "target/release/$t" >"out-$t.log" 2>&1 || true
    mkdir -p out && mv "out-$t.log" "out/$t.log"
done
printf '%-9s %12s %9s %8s %7s %6s\n' target inputs seconds exec/s crashes hangs
for t in "${targets[@]}"; do
    s="out/$t/default/fuzzer_stats"
    [ -f "$s" ] || { echo "$t: no stats (see fuzz/out/$t.log)"; continue; }
    get() { awk -F' *: *' -v k="$1" '$1==k {print $2}' "$s"; }
    printf '%-9s %12s %9s %8s %7s %6s\n' "$t" "$(get execs_done)" "$(get run_time)" \
        "$(get execs_per_sec)" "$(get saved_crashes)" "$(get saved_hangs)"
done
