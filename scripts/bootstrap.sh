#!/usr/bin/env bash
# Installs what a fresh Debian 12 machine lacks (as root, via apt) and configures + builds frostvdb.
# Used by scripts/run.sh and scripts/test.sh; safe to call again: it only installs what is missing
# and the build is incremental (ccache is used when present).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"

packages=(build-essential cmake ccache pkg-config
          libopenvdb-dev libboost-iostreams-dev libboost-program-options-dev
          libtbb-dev libeigen3-dev catch2 libtomlplusplus-dev libpng-dev
          python3-openvdb libopenvdb-tools libopenvdb-ax-tools
          libassimp-dev
          nlohmann-json3-dev  # run.json (core/Simulation.cpp)
          python3-matplotlib  # scripts/plot_csv.py draws the benchmark plots (docs/images) from their CSV
          blender)   # the add-on's tests run in real headless Blender (tests/blender, docs/blender.md)
"$here/scripts/install-packages.sh" "${packages[@]}"

build_type="${FROSTVDB_BUILD_TYPE:-Release}"
if [ ! -f build/CMakeCache.txt ]; then
  cmake -S . -B build -DCMAKE_BUILD_TYPE="$build_type" >&2
fi
jobs="$(nproc 2>/dev/null || echo 2)"
cmake --build build -j "$jobs" >&2
