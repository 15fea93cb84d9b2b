#!/usr/bin/env bash
# Installs what nimbus and its tests need on Debian 12 (idempotent). Safe to run again.
#   tools/setup.sh               runtime + test tools (Vulkan on the CPU, OpenVDB, OpenEXR tools)
#   tools/setup.sh --blender     also Blender 3.4 (for tools/render_blender.py and its test)
set -euo pipefail

packages=(
  mesa-vulkan-drivers libvulkan1   # Vulkan: lavapipe CPU device where there is no GPU
  libopenvdb-tools python3-openvdb # vdb_print + pyopenvdb: tests read our VDBs with real OpenVDB
  openexr                          # exrheader: tests read our EXRs with the reference tools
  python3-numpy                    # the OpenVDB comparison benchmark
)
if [[ "${1:-}" == "--blender" ]]; then packages+=(blender); fi

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  sudo=""
  if [[ $(id -u) -ne 0 ]]; then sudo="sudo"; fi
  echo "setup: installing ${missing[*]}" >&2
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null; then
  echo "setup: cargo not found: install Rust 1.85 or newer with rustup (https://rustup.rs)" >&2
  exit 1
fi
echo "setup: ok" >&2
