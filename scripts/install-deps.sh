#!/usr/bin/env bash
# Installs every Debian 12 package flamerig needs to build, test and run. Idempotent: packages already
# present are skipped, so a machine that has everything touches no network.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build pkg-config git python3
  libgtest-dev libgmock-dev
  libeigen3-dev libtbb-dev libyaml-cpp-dev zlib1g-dev libdeflate-dev libspdlog-dev libcli11-dev
  libopencv-dev libopencv-contrib-dev
  libmrcal-dev mrcal python3-mrcal python3-numpy
  libopenvdb-dev libopenvdb-tools libblosc-dev libboost-iostreams-dev libimath-dev libopenexr-dev
  libceres-dev
  libaravis-dev aravis-tools-cli aravis-tools libusb-1.0-0-dev iproute2
  colord-data
  libopenmpi-dev openmpi-bin
  blender
  libembree-dev libtinyobjloader-dev
  clang-14 libclang-rt-14-dev
  libhdf5-dev python3-h5py nlohmann-json3-dev libcpp-httplib-dev gnuplot-nox ffmpeg
  chromium
)

missing=()
for p in "${PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages present"
  exit 0
fi

echo "install-deps: installing ${#missing[@]} packages: ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
