#!/usr/bin/env bash
# The README's test command (and CI's, through .ci/run): set-up, a Release
# build with every test, then the same tests under AddressSanitizer and
# UndefinedBehaviorSanitizer in build-asan/. Non-zero on any failure.
#
# CI=true turns warnings into errors (OMM_WERROR=ON). Budget: CI has 2 cores
# and 30 minutes, so both builds use Ninja with -j2 (OMM_JOBS overrides) and the
# sanitizer pass neither builds nor runs tests labelled "slow" (heavy simulator
# renders and Monte-Carlo statistics, which run in the Release pass;
# `omm_test(... LABELS slow)` or `omm_test(... SLOW_TESTS filter)` marks them)
# or "acceptance".
set -euo pipefail
cd "$(dirname "$0")/.."

jobs=${OMM_JOBS:-2}
werror=OFF
if [ "${CI:-}" = "true" ]; then werror=ON; fi

bash scripts/setup.sh
# Share ccache hits between clones in different directories (CI's fresh clone).
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=true

echo "== Release build and tests (build/)"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DOMM_WERROR=$werror
cmake --build build -j "$jobs"
# Label acceptance: open issues' goals not yet met (tests/CMakeLists.txt).
ctest --test-dir build --output-on-failure -j "$jobs" -LE acceptance

echo "== AddressSanitizer + UBSan build and tests (build-asan/)"
cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DOMM_SANITIZE=ON \
  -DOMM_WERROR=$werror -DOMM_BUILD_BENCHMARKS=OFF -DOMM_UNBUILT_TEST_LABELS="slow;acceptance"
cmake --build build-asan -j "$jobs"
# Memory errors, leaks and undefined behaviour are fatal. scripts/lsan.supp
# lists the leaks inside prebuilt libraries (mrcal), each with its reason.
ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1} \
LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$PWD/scripts/lsan.supp:print_suppressions=0} \
UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1} \
  ctest --test-dir build-asan --output-on-failure -j "$jobs" -LE "slow|acceptance"

echo "== all tests passed"
