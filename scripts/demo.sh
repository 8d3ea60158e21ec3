#!/usr/bin/env bash
# The main job of the README: installs what is needed, builds the rotoscan program and runs the demo (a
# full scan on the virtual scanner, calibration included, ending in a colored point cloud, a mesh and a
# preview picture in ./rotoscan-demo/). Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup-debian.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo
cmake --build build -j "$(nproc)" --target rotoscan_cli
exec build/host/cli/rotoscan demo --out rotoscan-demo "$@"
