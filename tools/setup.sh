#!/usr/bin/env bash
# Installs what nimbus and its tests need on Debian 12 (idempotent). Safe to run again.
#   tools/setup.sh               runtime + test tools (Vulkan on the CPU, OpenGL through EGL, the
#                                Vulkan validation layer, spirv-val, OpenVDB, NanoVDB and OpenEXR
#                                tools; USD's Python module, PyPI usd-core pinned, in a venv at
#                                $NIMBUS_USD_VENV, default /opt/nimbus/usd)
#   tools/setup.sh --blender     also Blender 3.4 (for tools/render_blender.py and its test)
#   tools/setup.sh --preview     also ffmpeg (output.preview.movie and its test)
#   tools/setup.sh --farm        also Slurm and munge (for `nimbus farm` and its tests; a
#                                one-node cluster on localhost: tools/slurm-local.sh), and the
#                                Open Job Description CLI (PyPI openjd-cli, pinned) in a venv at
#                                $NIMBUS_OPENJD_VENV (default /opt/nimbus/openjd), for
#                                `farm submit --backend openjd` and tests/farm_openjd.rs
# Flags combine: tools/setup.sh --blender --preview --farm
set -euo pipefail

farm=0
packages=(
  mesa-vulkan-drivers libvulkan1   # Vulkan: lavapipe CPU device where there is no GPU
  libegl1 libegl-mesa0 libgl1-mesa-dri # OpenGL through EGL: the fallback without Vulkan (tests/run_e2e.rs)
  vulkan-validationlayers          # the Khronos validation layer: .ci/run's NIMBUS_GPU_VALIDATION pass
  spirv-tools                      # spirv-val: every shader's SPIR-V checked (tests/spirv_val.rs)
  libopenvdb-tools python3-openvdb # vdb_print + pyopenvdb: tests read our VDBs with real OpenVDB
  openexr                          # exrheader: tests read our EXRs with the reference tools
  python3-numpy                    # the OpenVDB comparison benchmark, tools/cloud_stats.py
  python3-netcdf4 python3-matplotlib # tools/cloud_stats.py: MicroHH's statistics files, its plots
  libnanovdb-tools                 # nanovdb_validate/print/convert: tests read our NanoVDB files
  python3-venv                     # the venv of USD's Python module (below)
)
for flag in "$@"; do
  case "$flag" in
    --blender) packages+=(blender) ;;
    --preview) packages+=(ffmpeg) ;;
    --farm) packages+=(slurmctld slurmd slurm-client munge python3-venv) farm=1 ;;
    *) echo "setup: unknown flag $flag (known: --blender, --preview, --farm)" >&2; exit 2 ;;
  esac
done

missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
sudo=""
if [[ $(id -u) -ne 0 ]]; then sudo="sudo"; fi
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}" >&2
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# Debian 12 ships Mesa 22.3, whose lavapipe runs our compute shaders at about half the speed of
# Mesa 25 (docs/PERFORMANCE.md "PBF": Mesa 25 reads storage buffers at per-lane indices with
# masked gathers, not a scalar loop over the SIMD lanes). Take mesa-vulkan-drivers from
# bookworm-backports there; later Debian releases ship Mesa 25 already.
codename=$(. /etc/os-release && echo "${VERSION_CODENAME:-}")
mesa=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)
if [[ "$codename" == "bookworm" ]] && dpkg --compare-versions "$mesa" lt 25; then
  list=/etc/apt/sources.list.d/bookworm-backports.sources
  if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    printf 'Types: deb\nURIs: http://deb.debian.org/debian\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' |
      $sudo tee "$list" >/dev/null
  fi
  echo "setup: installing mesa-vulkan-drivers from bookworm-backports (Mesa 25)" >&2
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
    -t bookworm-backports mesa-vulkan-drivers >/dev/null
fi

# The Open Job Description CLI, from PyPI into its own venv (Debian's python3 is externally
# managed). The version is pinned: it is the one tests/farm_openjd.rs was written against.
OPENJD_CLI_VERSION=0.8.0
if ((farm)); then
  venv=${NIMBUS_OPENJD_VENV:-/opt/nimbus/openjd}
  if ! "$venv/bin/openjd" --version 2>/dev/null | grep -q "$OPENJD_CLI_VERSION"; then
    echo "setup: installing openjd-cli $OPENJD_CLI_VERSION into $venv" >&2
    $sudo mkdir -p "$(dirname "$venv")"
    $sudo python3 -m venv "$venv"
    $sudo "$venv/bin/pip" install -q --disable-pip-version-check "openjd-cli==$OPENJD_CLI_VERSION"
  fi
  echo "setup: openjd: $venv/bin/openjd (nimbus finds it through NIMBUS_OPENJD or PATH)" >&2
fi

# USD's Python module (PyPI usd-core, pinned: tests/export_usd.rs was written against it) in a
# venv of Debian's own python3 with its system packages, so `pxr` and `pyopenvdb` import together.
USD_CORE_VERSION=25.11
usd_venv=${NIMBUS_USD_VENV:-/opt/nimbus/usd}
usd_have=$("$usd_venv/bin/pip" show usd-core 2>/dev/null | sed -n 's/^Version: //p' || true)
if [[ "$usd_have" != "$USD_CORE_VERSION" ]]; then
  echo "setup: installing usd-core $USD_CORE_VERSION into $usd_venv" >&2
  $sudo mkdir -p "$(dirname "$usd_venv")"
  $sudo /usr/bin/python3 -m venv --system-site-packages "$usd_venv"
  $sudo "$usd_venv/bin/pip" install -q --disable-pip-version-check "usd-core==$USD_CORE_VERSION"
fi

if ! command -v cargo >/dev/null; then
  echo "setup: cargo not found: install Rust 1.85 or newer with rustup (https://rustup.rs)" >&2
  exit 1
fi
echo "setup: ok" >&2
