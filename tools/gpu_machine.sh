#!/usr/bin/env bash
# The prepared run for a machine with a datacenter GPU (issue 15, docs/PERFORMANCE.md
# "Datacenter GPU"): one script, so that a short lease of such a machine is spent measuring.
#
#   tools/gpu_machine.sh prepare        here: release build, the Vulkan loader's .debs into .gl/,
#                                       the wheels of SPlisHSPlasH and numpy for the machine's
#                                       Python into .whl/
#   tools/gpu_machine.sh run [OUT]      there: carry target/release/nimbus, .gl and .whl
#
# `run` does, in order, writing every result under OUT ($OUT, else ./gpu-machine-out):
#   1. finds out whether wgpu sees the NVIDIA GPU through Vulkan (the loader from .gl, the
#      driver's ICD from the machine), and records the adapter nimbus opens (adapter.json);
#      if wgpu only sees a CPU adapter it says so and stops (a lavapipe figure on that machine
#      is no GPU figure);
#   2. `nimbus bench pbf --particles 1000000` from rest and disordered (pbf-1m-*.json), and the
#      full step with adaptivity, cloud physics and smoothing: the paper's two scenarios at
#      full size, `nimbus bench table1 --scale 1` (table1.json);
#   3. the SPlisHSPlasH anchor on all the machine's cores, side by side with nimbus on the GPU in
#      the same scene (tools/bench_pbf_vs_splishsplash.py, block scene, 1M particles:
#      side-by-side.md).
# Sizes can be cut for a try on a CPU machine: NIMBUS_GPU_PARTICLES, NIMBUS_GPU_TABLE1_SCALE,
# NIMBUS_GPU_ALLOW_CPU=1 (goes on with a CPU adapter).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
cd "$ROOT"
PY_TAG=${NIMBUS_GPU_PY:-3.12}
SPL=pysplishsplash==2.19.0

prepare() {
    set -e
    cargo build --release
    grep -qx '/.gl/' .git/info/exclude 2>/dev/null || echo /.gl/ >>.git/info/exclude
    grep -qx '/.whl/' .git/info/exclude 2>/dev/null || echo /.whl/ >>.git/info/exclude
    mkdir -p .gl .whl /tmp/amd64/partial
    local o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
    # shellcheck disable=SC2086
    apt-get $o update -qq
    # shellcheck disable=SC2086
    (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version "$PY_TAG" \
        --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl "$SPL" numpy
    ls -l target/release/nimbus .gl .whl
    echo "carry: target/release/nimbus .gl .whl; command: tools/gpu_machine.sh run \"\$OUT\""
}

# The adapter nimbus opens, as JSON (from a tiny `bench pbf`).
probe_adapter() {
    "$NIMBUS" bench pbf --particles 8000 --steps 1 --warmup 1 2>"$OUT/probe.err" |
        python3 -c 'import json,sys; d=json.load(sys.stdin); print(json.dumps({"adapter": d["adapter"], "gpu_timestamps": d["gpu_timestamps"]}))'
}

run() {
    OUT=${1:-${OUT:-$ROOT/gpu-machine-out}}
    mkdir -p "$OUT"
    : >"$OUT/bench.err"
    NIMBUS=${NIMBUS:-$ROOT/target/release/nimbus}
    export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/nimbus-xdg}
    mkdir -p -m 0700 "$XDG_RUNTIME_DIR"
    local particles=${NIMBUS_GPU_PARTICLES:-1000000}
    local scale=${NIMBUS_GPU_TABLE1_SCALE:-1}
    local cores
    cores=$(nproc)
    {
        date -u +%FT%TZ
        uname -a
        nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 || true
        echo "cores: $cores"
    } >"$OUT/machine.txt"

    # 1. Vulkan: the loader from .gl when the machine has none, the NVIDIA ICD from the driver.
    if [ -d .gl ] && ! ldconfig -p | grep -q libvulkan.so.1; then
        for f in .gl/*.deb; do dpkg -x "$f" /; done
        ldconfig
    fi
    local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    local probe
    probe=$(probe_adapter)
    if ! grep -qi nvidia <<<"$probe" && [ -f "$icd" ]; then
        export VK_DRIVER_FILES=$icd
        export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
        probe=$(probe_adapter)
    fi
    if [ -z "$probe" ]; then
        echo '{"adapter": null}' >"$OUT/adapter.json"
        echo "no adapter: wgpu found no Vulkan device (probe.err)" >&2
        return 4
    fi
    echo "$probe" >"$OUT/adapter.json"
    echo "adapter: $probe"
    if grep -qi llvmpipe <<<"$probe" && [ "${NIMBUS_GPU_ALLOW_CPU:-0}" != 1 ]; then
        echo "wgpu sees only llvmpipe: the NVIDIA GPU is not visible through Vulkan; stopping" >&2
        return 4
    fi

    # 2. nimbus alone: the PBF step at 1M (periodic cube, as docs/PERFORMANCE.md "PBF") and the
    # full step of the paper's scenarios.
    for w in 1 30; do
        "$NIMBUS" bench pbf --particles "$particles" --steps 10 --warmup "$w" \
            >"$OUT/pbf-1m-warmup$w.json" 2>>"$OUT/bench.err"
        echo "bench pbf --particles $particles --warmup $w: rc $?"
    done
    "$NIMBUS" bench table1 --scale "$scale" >"$OUT/table1.json" 2>>"$OUT/bench.err"
    echo "bench table1 --scale $scale: rc $?"

    # 3. SPlisHSPlasH on every core, nimbus on the GPU, the same block scene.
    # (a venv without pip, filled by this python's pip from the carried wheels, numpy too: a
    # venv does not see the packages of a python that itself lives in a venv; SPlisHSPlasH
    # finds its models beside the venv's python, in bin/data)
    local venv=${NIMBUS_SPL_VENV:-/tmp/nimbus-splvenv}
    if [ -z "${NIMBUS_SPL_VENV:-}" ] && compgen -G ".whl/pysplishsplash-*.whl" >/dev/null; then
        python3 -m venv --without-pip "$venv" &&
            PIP_ROOT_USER_ACTION=ignore python3 -m pip install -q --no-index --no-deps --prefix "$venv" .whl/*.whl
    fi
    NIMBUS_SPL_VENV=$venv python3 tools/bench_pbf_vs_splishsplash.py --nimbus "$NIMBUS" \
        --particles "$particles" --warmups 1,30 --steps 10 --threads "$cores" \
        --work /tmp/nimbus-splbench >"$OUT/side-by-side.md" 2>>"$OUT/bench.err"
    echo "side by side: rc $?"
    tail -n 20 "$OUT/bench.err" >&2 || true
}

case "${1:-}" in
prepare) prepare ;;
run) shift; run "$@" ;;
*)
    sed -n '2,22p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
    ;;
esac
