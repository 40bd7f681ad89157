#!/usr/bin/env bash
# One step of smoke around the Stanford bunny (scenes/fluid/bunny3d.xml: closed mesh, free slip by Walk-on-Spheres on
# the vector potential, RK4 backtraces) with the thesis' 128 walks per velocity query (64 antithetic gradient samples,
# `-D spp=64`), at the given cache resolutions. Issue 15's performance point: the thesis ran the bunny at 128^3 with
# 128 walks per query, about 70 s per step on four Tesla V100s (Sec. 5.4; quoted, not measured here).
#
#   bench/bench_bunny3d.sh [RES...]        # default 32; e.g. bench/bench_bunny3d.sh 32 48
#
# Per resolution, two runs of one step (dt 0.1, end 0.1, no frames) on all cores: spp 64 and spp 1 (2 walks per
# query). Both build the same scene, mesh and cache; they differ only in the walks, so
#     walks per CPU-second = (walks_64 - walks_1) / (CPU_64 - CPU_1)
# and the CPU seconds of the 128-walk step are CPU_64 minus the set-up (CPU_1 less its own walks at that rate). CPU
# is user + sys of the process (GNU time), the figure that holds on a shared machine; wall time is printed too. The
# extrapolation to 128^3 scales the measured walks per fluid cell and step by the number of cells (steps per walk
# do not depend on the cache: the walk's epsilon is relative to the domain).
# Environment: BUILD_DIR (default build), THREADS (default: all cores).
set -euo pipefail
cd "$(dirname "$0")/.."
RES=("$@")
((${#RES[@]})) || RES=(32)
KELVIN="${BUILD_DIR:-build}/bin/kelvin"
THREADS="${THREADS:-$(nproc)}"
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT

# Runs one step; prints "wall cpu walks".
run() {
  local res=$1 spp=$2
  /usr/bin/time -f "%e %U %S" -o "$OUT/time" "$KELVIN" scenes/fluid/bunny3d.xml -D res="$res" -D spp="$spp" \
    -D dt=0.1 -D end=0.1 -D every=0 -t "$THREADS" -q -o "$OUT/bunny.png" --stats "$OUT/stats.json" \
    >/dev/null 2>"$OUT/err" || { cat "$OUT/err" >&2; exit 1; }
  local walks
  walks=$(/usr/bin/python3 -c "import json,sys; print(int(json.load(open(sys.argv[1]))['statistics']['fluid.wos_walks']['value']))" "$OUT/stats.json")
  awk -v w="$walks" '{ printf "%s %.3f %s\n", $1, $2 + $3, w }' "$OUT/time"
}

echo "# bench_bunny3d: $THREADS threads on $(nproc) cores ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'))"
echo "# load average at start: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "| cache | walks per step | wall s (spp 64) | CPU s per step | walks per CPU-second | CPU s per step at 128^3 (extrapolated) |"
echo "|---|---:|---:|---:|---:|---:|"
for res in "${RES[@]}"; do
  read -r w64 c64 k64 <<<"$(run "$res" 64)"
  read -r w1 c1 k1 <<<"$(run "$res" 1)"
  awk -v res="$res" -v w64="$w64" -v c64="$c64" -v k64="$k64" -v c1="$c1" -v k1="$k1" 'BEGIN {
    rate = (k64 - k1) / (c64 - c1)
    step = c64 - (c1 - k1 / rate)
    big = k64 * (128 / res) ^ 3 / rate
    printf "| %d^3 | %.3g | %.1f | %.1f | %.3g | %.3g (%.1f h on 2 cores) |\n", res, k64, w64, step, rate, big, big / 2 / 3600
  }'
done
echo "# load average at end: $(cut -d' ' -f1-3 /proc/loadavg)"
