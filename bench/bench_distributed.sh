#!/usr/bin/env bash
# Strong scaling of distributed runs (issue 21, docs/distributed.md): one render, one Metropolis run and one 3D fluid
# run, from 1 to 2 MPI ranks, against the same work on threads of one process. Interleaved rounds (the machine is
# shared): every round runs each mode once, in turn; the table gives medians of wall time and CPU time (user + sys
# of all processes, mpirun included) and the speed-up of 2 ranks over 1 rank.
#
#   bench/bench_distributed.sh [ROUNDS] [CASE...]      # default 5 rounds; cases: render mlt fluid2d fluid3d
#
# Modes: "1 rank"  = mpirun -np 1 --bind-to none kelvin -t 1
#        "2 ranks" = mpirun -np 2 --bind-to none kelvin -t 1   (one thread per rank)
#        "2 threads" = kelvin -t 2                             (one process, no MPI)
# Environment: BUILD_DIR (default build).
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS="${1:-5}"
shift || true
CASES=("$@")
((${#CASES[@]})) || CASES=(render mlt fluid2d fluid3d)
KELVIN="${BUILD_DIR:-build}/bin/kelvin"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT

args_of() {
  case "$1" in
    render) echo "scenes/render/cornell-box.xml -D res=256 --spp 48" ;;
    mlt) echo "scenes/render/mlt-study.xml -D variant=drmlt-orbital -D res=128 --spp 24" ;;
    fluid2d) echo "scenes/fluid/taylor_green.xml -D res=256 -D spp=512 -D end=0.2 -D every=0" ;;
    fluid3d) echo "scenes/fluid/vortex_ring.xml -D res=64 -D spp=64 -D end=0.4 -D every=0" ;;
    *) echo "unknown case $1" >&2; exit 2 ;;
  esac
}

# Prints "wall cpu" of one run of the command (GNU time: elapsed, user + sys of the process and its children).
timed() {
  /usr/bin/time -f "%e %U %S" -o "$OUT/time" "$@" >/dev/null 2>"$OUT/err" || { cat "$OUT/err" >&2; exit 1; }
  awk '{ printf "%s %.3f\n", $1, $2 + $3 }' "$OUT/time"
}

median() { sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'; }

echo "# bench_distributed: $ROUNDS interleaved rounds on $(nproc) cores; load average at start: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "| case | mode | wall (s) | CPU (s) | speed-up (wall) vs 1 rank |"
echo "|---|---|---:|---:|---:|"
for c in "${CASES[@]}"; do
  read -r -a A <<<"$(args_of "$c")"
  : >"$OUT/$c.1rank"; : >"$OUT/$c.2ranks"; : >"$OUT/$c.2threads"
  for ((r = 0; r < ROUNDS; ++r)); do
    timed mpirun -np 1 --bind-to none --quiet "$KELVIN" "${A[@]}" -t 1 -q -o "$OUT/a.exr" >>"$OUT/$c.1rank"
    timed mpirun -np 2 --bind-to none --quiet "$KELVIN" "${A[@]}" -t 1 -q -o "$OUT/b.exr" >>"$OUT/$c.2ranks"
    timed "$KELVIN" "${A[@]}" -t 2 -q -o "$OUT/c.exr" >>"$OUT/$c.2threads"
  done
  w1=$(cut -d' ' -f1 "$OUT/$c.1rank" | median)
  for m in 1rank 2ranks 2threads; do
    w=$(cut -d' ' -f1 "$OUT/$c.$m" | median)
    u=$(cut -d' ' -f2 "$OUT/$c.$m" | median)
    label=${m/1rank/1 rank}; label=${label/2ranks/2 ranks}; label=${label/2threads/2 threads, 1 process}
    echo "| $c | $label | $w | $u | $(awk -v a="$w1" -v b="$w" 'BEGIN { printf "%.2fx", a / b }') |"
  done
done
echo "# load average at end: $(cut -d' ' -f1-3 /proc/loadavg)"
