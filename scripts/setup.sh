#!/usr/bin/env bash
# Installs every Debian 12 package omm needs to build, test and run the demo.
# Idempotent: when all are installed it does nothing (no apt-get at all).
# Runs as root or, if not root, through sudo.
#   OMM_SETUP_DRY_RUN=1 bash scripts/setup.sh   # only list what is missing
set -euo pipefail

packages=(
  # build tools
  cmake ninja-build g++ pkg-config ccache
  # calibration, geometry, optimisation
  libmrcal-dev python3-mrcal libsuitesparse-dev libopencv-dev libceres-dev libeigen3-dev libapriltag-dev colmap
  # files, command line, logging
  libyaml-cpp-dev nlohmann-json3-dev libcli11-dev libfmt-dev libspdlog-dev libsqlite3-dev libssl-dev libdeflate-dev
  # image files: PNG of other kinds, TIFF, JPEG
  libspng-dev libtiff-dev libturbojpeg0-dev
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev
  # GDAL's gdalinfo: a test reads the mosaic's placement (its world file) as GIS tools do
  gdal-bin
  # headless browser for the HTML report's test
  chromium
)

missing=()
for package in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$package")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages are installed"
  exit 0
fi
echo "setup: installing ${missing[*]}"
if [ "${OMM_SETUP_DRY_RUN:-0}" = "1" ]; then
  exit 0
fi

sudo=()
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "setup: not root and no sudo: install ${missing[*]} by hand" >&2; exit 1; }
  sudo=(sudo)
fi
"${sudo[@]}" apt-get update
"${sudo[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${missing[@]}"
