#!/usr/bin/env bash
# Mitsuba 3 conformance at a chosen budget: renders every scene of ../shared/mitsuba3-tests that Kelvin supports
# with Mitsuba's sample count times BUDGET (default 1, Mitsuba's own: 2e6 samples per image) and applies Mitsuba's
# z-test (tests/conformance/test_mitsuba3.cpp). Writes the images to OUT (default build/mitsuba3-conformance) and
# prints one line per scene, then the counts.
#
#   tools/mitsuba3_conformance.sh [BUDGET]        # e.g. 0.25 for a quick look
#
# Environment: BUILD_DIR (default build), KELVIN_MITSUBA3_TESTS (default ../shared/mitsuba3-tests), OUT.
set -uo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR="${BUILD_DIR:-build}"
OUT="${OUT:-$BUILD_DIR/mitsuba3-conformance}"
mkdir -p "$OUT"
cmake --build "$BUILD_DIR" --target test_conformance -j2 >/dev/null || exit 1
log="$OUT/conformance.log"
KELVIN_MITSUBA3_BUDGET="${1:-1}" KELVIN_MITSUBA3_OUTPUT="$OUT" \
  "$BUILD_DIR/bin/test_conformance" --gtest_filter='*PassesMitsubasZTest*' >"$log" 2>&1
grep -E "values rejected|not supported|known difference|participating media" "$log" | sed 's|^.*tests/scenes/||'
echo
echo "passed:            $(grep -c '^\[       OK \]' "$log")"
echo "known differences: $(grep -c 'known difference' "$log")"
echo "not supported:     $(grep -c 'not supported' "$log")"
echo "failed:            $(grep -c '^\[  FAILED  \] Mitsuba3' "$log")"
echo "images and log in $OUT"
