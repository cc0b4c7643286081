#!/usr/bin/env bash
# Installs the Debian packages diffphd needs to build and test (python3-matplotlib: the demo's
# chart and the bench charts, whose script has a self-test; clang-14 and libclang-rt-14-dev:
# the libFuzzer harnesses of scripts/fuzz.sh). --demo is kept for compatibility.
# Skips apt-get when everything is already installed. Run as root (or with sudo).
set -euo pipefail
packages=(build-essential cmake ninja-build ccache pkg-config
          libeigen3-dev libmetis-dev libsuitesparse-dev libopenblas-dev
          catch2 libcli11-dev liblbfgspp-dev nlohmann-json3-dev python3-matplotlib
          clang-14 libclang-rt-14-dev)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "install-deps: installing ${missing[*]}"
  sudo_cmd=()
  [[ $(id -u) -eq 0 ]] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends \
    "${missing[@]}"
else
  echo "install-deps: all ${#packages[@]} packages present"
fi
if [[ -x /usr/local/cuda/bin/nvcc ]]; then
  echo "install-deps: CUDA toolkit found at /usr/local/cuda (diffphd::cuda will be built)"
else
  echo "install-deps: no CUDA toolkit at /usr/local/cuda (diffphd::cuda will be skipped)"
fi
