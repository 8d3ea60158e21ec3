#!/usr/bin/env bash
# Fuzzing of the readers of hostile input (issue 20): bundle.json, PLY, scene JSON, calib.yaml, image files
# and a webcam's MJPEG frames (host/fuzz/), and the protocol decoder (protocol/fuzz/). Builds the libraries
# with clang, libFuzzer's coverage, ASan and UBSan into build-fuzz/ (or $ROTOSCAN_FUZZ_BUILD), then runs
# each target from seeds taken from data/ and from a small rendered bundle.
#   scripts/fuzz.sh [RUNS] [PROTOCOL_RUNS]   opt-in: a fixed number of executions each (defaults 1000000 and
#                                            10000000)
#   scripts/fuzz.sh --smoke SECONDS          the smoke run (CTest fuzz.smoke, opt-in with ROTOSCAN_FUZZ_SMOKE=1): each
#                                            target for SECONDS
#   scripts/fuzz.sh --build-only             the build alone (CTest fuzz.build, opt-in the same way)
# Seeds: ROTOSCAN_FUZZ_BUNDLE=DIR gives a rendered bundle (bundle.json, truth/rig.yaml, a frame); else, if
# ROTOSCAN_CLI is the rotoscan program, a tiny one is rendered; else minimal seeds written here.
# Prints each target's executions, time and new coverage; exits non-zero on the first finding (the input
# is left in the build's findings/), 77 (CTest's "skipped") when clang or its libFuzzer runtime is missing.
set -euo pipefail
mode=runs
smoke_seconds=0
case "${1:-}" in
  --smoke) mode=smoke; smoke_seconds=${2:?--smoke SECONDS} ;;
  --build-only) mode=build ;;
esac
# The CTest entries are opt-in: the clang build of their own is ~10 min on 2 cores from scratch, too much for
# every CI run (ROTOSCAN_FUZZ_SMOKE=1 ctest -L fuzz).
if [[ $mode != runs && "${ROTOSCAN_FUZZ_SMOKE:-0}" != 1 ]]; then
  echo "fuzz smoke run is opt-in: ROTOSCAN_FUZZ_SMOKE=1 ctest -L fuzz"
  exit 77
fi
runs=1000000
protocol_runs=10000000
if [[ $mode == runs ]]; then
  runs=${1:-1000000}
  protocol_runs=${2:-10000000}
fi
root=$(cd "$(dirname "$0")/.." && pwd)
build="${ROTOSCAN_FUZZ_BUILD:-$root/build-fuzz}"
cc=$(command -v clang || command -v clang-14 || true)
cxx=$(command -v clang++ || command -v clang++-14 || true)
if [[ -z "$cc" || -z "$cxx" ]]; then
  echo "clang not found: fuzzing skipped"
  exit 77
fi
probe=$(mktemp -d)
trap 'rm -rf "$probe"' EXIT
printf 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) { return 0; }\n' >"$probe/p.cc"
if ! "$cxx" -fsanitize=fuzzer "$probe/p.cc" -o "$probe/p" 2>"$probe/err"; then
  echo "clang has no libFuzzer runtime (Debian: libclang-rt-14-dev): fuzzing skipped"
  cat "$probe/err"
  exit 77
fi
launcher=()
if command -v ccache >/dev/null; then
  launcher=(-DCMAKE_C_COMPILER_LAUNCHER=ccache -DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
fi
targets=(rotoscan_bundle_json_fuzz rotoscan_ply_fuzz rotoscan_scene_fuzz rotoscan_calib_yaml_fuzz
  rotoscan_image_fuzz rotoscan_protocol_fuzz)
# The smoke run follows fuzz.build (CTest fixture): configure only if that has not.
[[ $mode == smoke && -f "$build/build.ninja" ]] ||
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER="$cc" \
  -DCMAKE_CXX_COMPILER="$cxx" -DROTOSCAN_BUILD_FUZZERS=ON -DROTOSCAN_SANITIZE=ON -DROTOSCAN_BUILD_TESTS=OFF \
  -DROTOSCAN_BUILD_BENCHMARKS=OFF -DROTOSCAN_BUILD_CLI=OFF "${launcher[@]}" >/dev/null
if cmake --build "$build" --target help 2>/dev/null | grep 'rotoscan_mjpeg_fuzz' >/dev/null; then  # no -q: pipefail
  targets+=(rotoscan_mjpeg_fuzz)
fi
nice cmake --build "$build" --target "${targets[@]}"
[[ $mode == build ]] && exit 0

seeds="$build/seeds"
rm -rf "$seeds" "$build/findings"
mkdir -p "$seeds"/{bundle_json,ply,scene,calib_yaml,image,mjpeg,protocol} "$build/findings"
cp "$root"/data/scenes/*.json "$seeds/scene/"
# A bundle.json, a rig.yaml and a frame as our writers write them: from a rendered bundle if one is given
# or can be rendered, else minimal ones written here.
bundle="${ROTOSCAN_FUZZ_BUNDLE:-}"
if [[ -z "$bundle" && -n "${ROTOSCAN_CLI:-}" ]]; then
  printf '{"seed": 3, "steps": 2, "camera": {"width": 64, "height": 48, "hfov_deg": 8, "supersampling": 1},
    "objects": [{"type": "sphere", "radius_mm": 10}]}\n' >"$probe/scene.json"
  "$ROTOSCAN_CLI" --no-progress simulate "$probe/scene.json" --out "$probe/bundle" --threads 1 >/dev/null
  bundle="$probe/bundle"
fi
if [[ -n "$bundle" ]]; then
  cp "$bundle/bundle.json" "$seeds/bundle_json/"
  cp "$bundle/truth/rig.yaml" "$seeds/calib_yaml/"
  frame=$(find "$bundle" -maxdepth 2 -name '*.png' -size -64k | head -1)
  [[ -n "$frame" ]] && cp "$frame" "$seeds/image/"
fi
printf 'ply\nformat ascii 1.0\ncomment c\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n1 2 3 255 0 0\n4 5 6 0 255 0\n' \
  >"$seeds/ply/ascii.ply"
# A JPEG from data/ (640 x 480): the MJPEG target reads its first byte as the size to expect (0: 640 x 480).
jpeg="$root/data/calib/opencv-left/left01.jpg"
cp "$jpeg" "$seeds/image/"
{ printf '\x00'; cat "$jpeg"; } >"$seeds/mjpeg/left01"
for v in "$root"/protocol/vectors/*.hex; do
  xxd -r -p "$v" >"$seeds/protocol/$(basename "$v" .hex)" 2>/dev/null || true
done

run() {  # target, seeds, runs, max_len
  local start end limit
  start=$(date +%s)
  limit=(-runs="$3")
  [[ $mode == smoke ]] && limit=(-max_total_time="$smoke_seconds")
  "$build/$1" "${limit[@]}" -timeout=20 -seed=20261123 -max_len="$4" -print_final_stats=1 -artifact_prefix="$build/findings/" \
    "$2" 2>"$build/$1.log" || { tail -40 "$build/$1.log"; echo "$1: FINDING (see $build/findings/)"; exit 1; }
  end=$(date +%s)
  echo "$1: $(grep -E 'stat::number_of_executed_units' "$build/$1.log" | awk '{print $2}') executions in $((end - start)) s, $(grep -E 'stat::new_units_added' "$build/$1.log" | awk '{print $2}') new units, no finding"
}
find "$build" -name 'rotoscan_*_fuzz' -type f -executable -exec ln -sf {} "$build/" \; 2>/dev/null || true
run rotoscan_bundle_json_fuzz "$seeds/bundle_json" "$runs" 8192
run rotoscan_ply_fuzz "$seeds/ply" "$runs" 4096
run rotoscan_scene_fuzz "$seeds/scene" "$runs" 4096
run rotoscan_calib_yaml_fuzz "$seeds/calib_yaml" "$runs" 4096
run rotoscan_image_fuzz "$seeds/image" "$runs" 65536
if [[ -x "$build/rotoscan_mjpeg_fuzz" ]]; then
  run rotoscan_mjpeg_fuzz "$seeds/mjpeg" "$runs" 65536
fi
run rotoscan_protocol_fuzz "$seeds/protocol" "$protocol_runs" 512
