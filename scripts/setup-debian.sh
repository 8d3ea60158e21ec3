#!/usr/bin/env bash
# Installs every Debian package Rotoscan needs to build, test, run the demo and cross-build the firmware.
# Idempotent: installs only what is missing, and says what. Debian 12; run as root (or with sudo).
set -euo pipefail

packages=(
  # build tools
  build-essential cmake ninja-build pkg-config git ccache
  # host library
  libeigen3-dev libopencv-dev libopencv-contrib-dev libceres-dev libusb-1.0-0-dev libopen3d-dev
  libembree-dev nlohmann-json3-dev libcli11-dev libaravis-dev libjpeg-dev libpng-dev
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev umockdev libumockdev-dev clang libclang-rt-14-dev
  # firmware cross build and flashing
  gcc-arm-none-eabi libnewlib-arm-none-eabi dfu-util
  # the firmware image on an emulated Cortex-M4 (issue 18), the API reference (issue 17)
  libunicorn-dev doxygen
  # frames from a renderer we did not write (issue 15: laser_povray_test)
  povray
)

missing=()
for p in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${db:Status-Status}' "$p" 2>/dev/null || true)
  [ "$status" = "installed" ] || missing+=("$p")
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} Debian packages are installed"
  exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "setup: need root (or sudo) to install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
echo "setup: installing ${#missing[@]} Debian packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "setup: done"
