#!/usr/bin/env bash
# A calibration session on a Slurm cluster: the kernels of each shot measured by its
# own array task, then one job, started when every task has succeeded, that fits the
# profile from the kernels files.
#
#   scripts/slurm_kernels.sh submit SHOTS.tsv OUT_DIR PROFILE.json   on the login node
#   scripts/slurm_kernels.sh task SHOTS.tsv OUT_DIR                  one array task (the
#                                       shot on line SLURM_ARRAY_TASK_ID, counting from 0)
#   scripts/slurm_kernels.sh calibrate SHOTS.tsv OUT_DIR PROFILE.json   the last job
#
# SHOTS.tsv lists one shot a line, tab-separated: the shot file, then optionally its
# focal length (mm) and f-number where EXIF lacks them; blank lines and lines starting
# with # are skipped. From a manifest (relative paths are relative to its folder):
#   jq -r '.shots[] | [.path, .focal_mm, .f_number] | @tsv' manifest.json > shots.tsv
# Each shot's kernels go to OUT_DIR/<shot file name without extension>.kernels.json
# (so two shots may not share a name); relative paths are relative to the folder
# the jobs were submitted from. The profile is then the one
# `lensblur calibrate --manifest` makes on the same shots: the same kernels, taken in
# the list's order.
#
# Environment: LENSBLUR, the lensblur binary (default: lensblur on PATH);
# LENSBLUR_CHART, the chart spec printed when it is not the default 24 × 16 one;
# CALIBRATE_ARGS, more options for `lensblur calibrate` (e.g. "--alpha 6 --beta 3").
# Resources below suit one 24 MP shot a task; override them at submission with
# sbatch's own environment variables (SBATCH_TIMELIMIT, SBATCH_PARTITION, ...).
#
#SBATCH --job-name=lensblur
#SBATCH --cpus-per-task=4
#SBATCH --mem=4G
#SBATCH --time=01:00:00
#SBATCH --output=lensblur-%A_%a.log
set -euo pipefail

usage() {
    echo "usage: $0 submit|task|calibrate SHOTS.tsv OUT_DIR [PROFILE.json]" >&2
    exit 2
}

lensblur=${LENSBLUR:-lensblur}
chart_args=()
if [ -n "${LENSBLUR_CHART:-}" ]; then
    chart_args=(--chart "$LENSBLUR_CHART")
fi

# The list's shot lines, in order, into the array `lines`.
read_shots() {
    local line
    lines=()
    while IFS= read -r line || [ -n "$line" ]; do
        line=${line%$'\r'}
        case $line in
        '' | '#'*) continue ;;
        esac
        lines+=("$line")
    done <"$1"
    if [ ${#lines[@]} -eq 0 ]; then
        echo "$1: lists no shots" >&2
        exit 1
    fi
}

# Where the kernels of the shot file $2 go, in the folder $1.
kernels_path() {
    local name
    name=$(basename -- "$2")
    printf '%s/%s.kernels.json\n' "$1" "${name%.*}"
}

[ $# -ge 3 ] || usage
mode=$1
list=$2
out_dir=$3
read_shots "$list"

case $mode in
submit)
    [ $# -eq 4 ] || usage
    profile=$4
    dupes=$(for l in "${lines[@]}"; do
        IFS=$'\t' read -r shot _ <<<"$l"
        kernels_path "$out_dir" "$shot"
    done | sort | uniq -d)
    if [ -n "$dupes" ]; then
        echo "$list: two shots would write the same kernels file: $dupes" >&2
        exit 1
    fi
    mkdir -p -- "$out_dir"
    script=$(realpath -- "$0")
    array=$(sbatch --parsable --array="0-$((${#lines[@]} - 1))" \
        "$script" task "$list" "$out_dir")
    array=${array%%;*}
    final=$(sbatch --parsable --dependency="afterok:$array" \
        --output=lensblur-%j-calibrate.log "$script" calibrate "$list" "$out_dir" "$profile")
    echo "kernels: job array $array (${#lines[@]} shots); profile: job ${final%%;*}"
    ;;
task)
    [ $# -eq 3 ] || usage
    index=${SLURM_ARRAY_TASK_ID:?task runs as a Slurm array task (SLURM_ARRAY_TASK_ID)}
    if [ "$index" -ge ${#lines[@]} ]; then
        echo "$list: no shot $index (${#lines[@]} listed)" >&2
        exit 1
    fi
    IFS=$'\t' read -r shot focal aperture _ <<<"${lines[$index]}"
    setting=()
    if [ -n "${focal:-}" ]; then setting+=(--focal "$focal"); fi
    if [ -n "${aperture:-}" ]; then setting+=(--aperture "$aperture"); fi
    mkdir -p -- "$out_dir"
    # With the arrays: calibration fits the kernel-shape model from them.
    "$lensblur" kernels "$shot" --with-kernels --out "$(kernels_path "$out_dir" "$shot")" \
        "${setting[@]}" "${chart_args[@]}"
    ;;
calibrate)
    [ $# -eq 4 ] || usage
    profile=$4
    files=()
    for l in "${lines[@]}"; do
        IFS=$'\t' read -r shot _ <<<"$l"
        files+=("$(kernels_path "$out_dir" "$shot")")
    done
    extra=()
    read -r -a extra <<<"${CALIBRATE_ARGS:-}"
    "$lensblur" calibrate --kernels "${files[@]}" --out "$profile" \
        "${chart_args[@]}" "${extra[@]}"
    ;;
*)
    usage
    ;;
esac
