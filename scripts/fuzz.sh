#!/usr/bin/env bash
# Opt-in fuzzing of the readers of hostile input (issue 20): bundle.json, PLY, scene JSON, calib.yaml
# (host/fuzz/) and the protocol decoder (protocol/fuzz/). Builds the libraries with clang, libFuzzer's
# coverage, ASan and UBSan into build-fuzz/, then runs each target for a fixed number of executions from
# seeds taken from data/ and from a small rendered bundle.
#   scripts/fuzz.sh [RUNS] [PROTOCOL_RUNS]      defaults: 1000000 and 10000000
# Prints each target's executions, time and new coverage; exits non-zero on the first finding (the input
# is left in build-fuzz/findings/).
set -euo pipefail
runs=${1:-1000000}
protocol_runs=${2:-10000000}
root=$(cd "$(dirname "$0")/.." && pwd)
build="$root/build-fuzz"
cc=$(command -v clang || command -v clang-14)
cxx=$(command -v clang++ || command -v clang++-14)
launcher=()
if command -v ccache >/dev/null; then
  launcher=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
fi
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER="$cc" \
  -DCMAKE_CXX_COMPILER="$cxx" -DROTOSCAN_BUILD_FUZZERS=ON -DROTOSCAN_SANITIZE=ON -DROTOSCAN_BUILD_TESTS=OFF \
  -DROTOSCAN_BUILD_BENCHMARKS=OFF -DROTOSCAN_BUILD_CLI=OFF "${launcher[@]}" >/dev/null
cmake --build "$build" --target rotoscan_bundle_json_fuzz rotoscan_ply_fuzz rotoscan_scene_fuzz \
  rotoscan_calib_yaml_fuzz rotoscan_protocol_fuzz

seeds="$build/seeds"
rm -rf "$seeds" "$build/findings"
mkdir -p "$seeds"/{bundle_json,ply,scene,calib_yaml,protocol} "$build/findings"
cp "$root"/data/scenes/*.json "$seeds/scene/"
# A bundle.json, a PLY and a rig.yaml as our writers write them: from the seeds' directory if a rendered
# bundle is given (ROTOSCAN_FUZZ_BUNDLE), else minimal ones written here.
if [[ -n "${ROTOSCAN_FUZZ_BUNDLE:-}" ]]; then
  cp "$ROTOSCAN_FUZZ_BUNDLE/bundle.json" "$seeds/bundle_json/"
  cp "$ROTOSCAN_FUZZ_BUNDLE/truth/rig.yaml" "$seeds/calib_yaml/"
fi
printf 'ply\nformat ascii 1.0\ncomment c\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n1 2 3 255 0 0\n4 5 6 0 255 0\n' \
  >"$seeds/ply/ascii.ply"
for v in "$root"/protocol/vectors/*.hex; do
  xxd -r -p "$v" >"$seeds/protocol/$(basename "$v" .hex)" 2>/dev/null || true
done

run() {  # target, seeds, runs, max_len
  local start end
  start=$(date +%s)
  "$build/$1" -runs="$3" -seed=20261123 -max_len="$4" -print_final_stats=1 -artifact_prefix="$build/findings/" \
    "$2" 2>"$build/$1.log" || { tail -40 "$build/$1.log"; echo "$1: FINDING (see $build/findings/)"; exit 1; }
  end=$(date +%s)
  echo "$1: $(grep -E 'stat::number_of_executed_units' "$build/$1.log" | awk '{print $2}') executions in $((end - start)) s, $(grep -E 'stat::new_units_added' "$build/$1.log" | awk '{print $2}') new units, no finding"
}
find "$build" -name 'rotoscan_*_fuzz' -type f -executable -exec ln -sf {} "$build/" \; 2>/dev/null || true
run rotoscan_bundle_json_fuzz "$seeds/bundle_json" "$runs" 8192
run rotoscan_ply_fuzz "$seeds/ply" "$runs" 4096
run rotoscan_scene_fuzz "$seeds/scene" "$runs" 4096
run rotoscan_calib_yaml_fuzz "$seeds/calib_yaml" "$runs" 4096
run rotoscan_protocol_fuzz "$seeds/protocol" "$protocol_runs" 512
