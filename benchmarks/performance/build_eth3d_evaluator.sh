#!/usr/bin/env bash
# Build the official ETH3D multi-view evaluation program from a source checkout.
#
#   benchmarks/performance/build_eth3d_evaluator.sh SRC_DIR BUILD_DIR
#
# SRC_DIR: a checkout of https://github.com/ETH3D/multi-view-evaluation (not part of this repository;
# never commit its code). BUILD_DIR receives the build; the binary is BUILD_DIR/ETH3DMultiViewEvaluation.
# Needs (Debian): libpcl-dev libeigen3-dev libboost-filesystem-dev libboost-system-dev cmake g++
#   apt-get -o DPkg::Lock::Timeout=900 install -y --no-install-recommends \
#       libpcl-dev libeigen3-dev libboost-filesystem-dev libboost-system-dev cmake g++
set -euo pipefail
if [ $# -ne 2 ]; then
    echo "usage: $0 SRC_DIR BUILD_DIR" >&2
    exit 2
fi
src=$(cd "$1" && pwd)
if [ ! -f "$src/CMakeLists.txt" ] || [ ! -f "$src/src/accuracy.cc" ]; then
    echo "$0: $src does not look like an ETH3D multi-view-evaluation checkout" >&2
    exit 2
fi
mkdir -p "$2"
build=$(cd "$2" && pwd)
cmake -S "$src" -B "$build" -DCMAKE_BUILD_TYPE=Release >"$build/cmake.log" 2>&1 || {
    tail -20 "$build/cmake.log" >&2; exit 1; }
cmake --build "$build" -j "${JOBS:-2}" >"$build/make.log" 2>&1 || { tail -30 "$build/make.log" >&2; exit 1; }
bin="$build/ETH3DMultiViewEvaluation"
[ -x "$bin" ] || { echo "$0: build finished but $bin is missing" >&2; exit 1; }
echo "$bin"
