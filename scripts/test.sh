#!/usr/bin/env bash
# The test command of the README: installs what is needed, builds everything (library, CLI, tests,
# benchmarks, the example against the installed package), and runs all the tests; then does the same
# under AddressSanitizer + UndefinedBehaviorSanitizer. Safe to run again (builds incrementally).
#   scripts/test.sh            both builds
#   scripts/test.sh --no-sanitize   the plain build only
set -euo pipefail
cd "$(dirname "$0")/.."

sanitize=1
for arg in "$@"; do
  case "$arg" in
    --no-sanitize) sanitize=0 ;;
    *) echo "usage: scripts/test.sh [--no-sanitize]" >&2; exit 2 ;;
  esac
done

bash scripts/setup-debian.sh
jobs=$(nproc)
# ccache (installed by the setup) makes a second run, or a fresh clone on the same machine, rebuild only what
# changed; CCACHE_BASEDIR lets clones at different paths share the cache.
launcher=()
if command -v ccache >/dev/null; then
  export CCACHE_BASEDIR="$PWD"
  launcher=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
fi

run_suite() {  # name, build dir, extra cmake args...
  local name=$1 dir=$2
  shift 2
  echo "== $name: configure, build and test in $dir"
  cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DROTOSCAN_WERROR=ON "${launcher[@]}" "$@"
  cmake --build "$dir" -j "$jobs"
  (cd "$dir" && ctest --output-on-failure -j "$jobs")
}

run_suite "plain" build
if [ "$sanitize" = 1 ]; then
  export ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
  run_suite "sanitized (ASan+UBSan)" build-asan -DROTOSCAN_SANITIZE=ON -DROTOSCAN_BUILD_BENCHMARKS=OFF
fi
echo "== all tests passed (${SECONDS} s)"
