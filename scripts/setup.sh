#!/usr/bin/env bash
# Sets up DeepC Workbench on a Debian machine: system libraries, .venv, the package.
#   scripts/setup.sh          what `deepc run` needs
#   scripts/setup.sh --test   plus what the tests need (test extras, Debian chromium)
# Idempotent and quick when nothing changed. Never pulls CUDA builds of torch: the CPU wheel
# torch==2.13.0 is installed first, so the package's torch range is already satisfied.
set -euo pipefail
cd "$(dirname "$0")/.."

with_tests=0
[ "${1:-}" = "--test" ] && with_tests=1

apt_packages=(libgl1 libegl1 libx11-6 libusb-1.0-0)   # open3d links these
[ "$with_tests" = 1 ] && apt_packages+=(chromium)
missing=()
for pkg in "${apt_packages[@]}"; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" -ne 0 ] && sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get -o DPkg::Lock::Timeout=900 update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get -o DPkg::Lock::Timeout=900 install -y -qq \
    --no-install-recommends "${missing[@]}" >/dev/null
fi

python_bin=$(command -v python3.11 || command -v python3)
"$python_bin" -c 'import sys; assert sys.version_info[:2] in ((3, 11), (3, 12)), sys.version' \
  || { echo "setup: needs Python 3.11 or 3.12, found $("$python_bin" --version)" >&2; exit 2; }
[ -x .venv/bin/python ] || "$python_bin" -m venv .venv

extras=""
[ "$with_tests" = 1 ] && extras="[test]"
stamp=".venv/.deepc-setup-$(cat pyproject.toml | sha1sum | cut -c1-12)${extras:+-test}"
pip_quiet() {  # pip's output goes to a log, shown only when pip fails
  .venv/bin/python -m pip "$@" --disable-pip-version-check >>.venv/setup.log 2>&1 \
    || { tail -40 .venv/setup.log >&2; echo "setup: pip $1 failed (log: .venv/setup.log)" >&2; exit 1; }
}
if [ ! -f "$stamp" ]; then
  echo "setup: installing Python packages into .venv (log: .venv/setup.log)"
  pip_quiet install "torch==2.13.0"
  pip_quiet install -e ".${extras}"
  pip_quiet check
  if .venv/bin/python -m pip list 2>/dev/null | grep -qi '^nvidia-'; then
    echo "setup: CUDA packages were pulled in; torch must be the CPU build" >&2; exit 1
  fi
  touch "$stamp"
fi
# Compile the numba kernels in a process of their own, so that every later run loads the same cached
# code (freshly compiled and cached code do not round identically; workbench/cli/compile_cache.py). Skipped
# while the sources (paths, sizes, mtimes: what numba's cache checks) and the cache are unchanged.
numba_stamp=".venv/.deepc-numba-$(find engine workbench -name '*.py' -printf '%p %s %T@\n' | sort | sha1sum | cut -c1-12)"
if [ ! -f "$numba_stamp" ] || ! ls engine/patchmatch/__pycache__/*.nbi >/dev/null 2>&1; then
  echo "setup: compiling the numba kernels (once per source change, about 2 minutes)"
  rm -f .venv/.deepc-numba-*
  NUMBA_THREADING_LAYER="${NUMBA_THREADING_LAYER:-workqueue}" .venv/bin/python -m workbench.cli.compile_cache \
    || { echo "setup: compiling the numba kernels failed" >&2; exit 1; }
  touch "$numba_stamp"
fi
echo "setup: ready ($(.venv/bin/deepc --version))"
