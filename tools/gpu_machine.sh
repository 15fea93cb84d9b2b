#!/usr/bin/env bash
# The prepared run for a machine with a datacenter GPU (issues 15 and 36, docs/PERFORMANCE.md
# "Datacenter GPU"): one call of the `device` tool, under 10 minutes on an H200, so that a short
# lease of such a machine is spent measuring, not debugging.
#
#   tools/gpu_machine.sh prepare [DIR]   here: builds and packs into DIR (default .gpu-machine/,
#                                        git-ignored) the release binary and the GPU suites' test
#                                        executables (payload.tar.xz), the Vulkan loader's and
#                                        EGL's .debs (gl/), the wheels of SPlisHSPlasH and numpy
#                                        for the machine's Python (whl/); checks the size
#   tools/gpu_machine.sh run [OUT]       there: device run with carry [".gpu-machine"] and the
#                                        command `tools/gpu_machine.sh run "$OUT"`
#
# `run` writes into OUT ($OUT, else ./gpu-machine-out) at most 8 files (what the device tool
# brings back): summary.md, results.jsonl (one JSON line per step), log.txt, and the hero
# shot's previews (hero-*.png) with its stats (hero-stats.jsonl). In order, each step skipped
# with a note when the time left (NIMBUS_GPU_BUDGET seconds in all, default 540) is too short:
#   1. the machine and the adapter nimbus opens (its driver, subgroup size, limits); if wgpu sees
#      only a CPU adapter it stops (a lavapipe figure on that machine is no GPU figure);
#   2. the GPU test suites on that adapter (tests/gpu_*.rs and the others that open a device);
#   3. `bench pbf` at 1M particles, from rest and disordered;
#   4. SPlisHSPlasH on every core side by side with nimbus on the GPU, 1M particles;
#   5. `bench step`, the full adaptive step of paper example 1 widened, at 1M; `bench pbf` and
#      `bench step` at 10M (the warm-ups stop in time: `bench step --max-seconds`);
#   6. the hero shot (pipelines/hero_cumulus_hd.yaml) at its production resolution for the
#      time left (at least two minutes are kept for it), its previews brought back.
# Sizes can be cut for a dry run on a CPU machine: NIMBUS_GPU_ALLOW_CPU=1 (go on with a CPU
# adapter), NIMBUS_GPU_PARTICLES (1M), NIMBUS_GPU_LARGE (10M), NIMBUS_GPU_STEP_WARMUP (frames
# before `bench step` measures, 40), NIMBUS_GPU_SPL_STEPS (10), NIMBUS_GPU_HERO (the hero
# config), NIMBUS_GPU_HERO_SET (extra --set arguments for it, space-separated),
# NIMBUS_GPU_SUITES (space-separated suite names), NIMBUS_GPU_BUDGET.
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
SELF=$ROOT/tools/$(basename "$0")
cd "$ROOT"
PY_TAG=${NIMBUS_GPU_PY:-3.12}
SPL=pysplishsplash==2.19.0
# every test executable that opens a device (docs/ARCHITECTURE.md "Across adapters"; the
# validation tripwire needs the Khronos layer, which the machine does not have)
SUITES_ALL="gpu_portability gpu_sort gpu_thermo gpu_adaptive gpu_pbf gpu_atmosphere gpu_capacity art_direction target_control"
# what the device tool carries: the tracked tree and this folder, 64 MiB in all
CARRY_LIMIT=$((64 << 20))

prepare() {
    set -e
    local dir=${1:-.gpu-machine}
    local exclude
    exclude="$(git rev-parse --git-common-dir)/info/exclude"
    grep -qx "/$dir/" "$exclude" 2>/dev/null || echo "/$dir/" >>"$exclude"
    rm -rf "$dir" && mkdir -p "$dir/gl" "$dir/whl" "$dir/stage/bin" "$dir/stage/tests"
    cargo build --release --locked
    strip -o "$dir/stage/bin/nimbus" target/release/nimbus
    # the test executables cargo builds (debug, as CI's), by suite name
    cargo test --locked --no-run --message-format=json 2>/dev/null |
        python3 -c '
import json, sys
want = set(sys.argv[1].split())
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") \
            and m["target"]["kind"] == ["test"] and m["target"]["name"] in want:
        print(m["target"]["name"], m["executable"])
' "$SUITES_ALL" >"$dir/suites.txt"
    while read -r name exe; do strip -o "$dir/stage/tests/$name" "$exe"; done <"$dir/suites.txt"
    [ "$(wc -l <"$dir/suites.txt")" -eq "$(wc -w <<<"$SUITES_ALL")" ] ||
        { echo "prepare: a suite's executable is missing ($dir/suites.txt)" >&2; exit 1; }
    # the tests find the binary and samples/ through the path they were built in
    echo "$ROOT" >"$dir/stage/tests/root"
    # the tree the device tool copies has no .git
    git describe --always --dirty >"$dir/stage/commit"
    # one xz stream with a 64 MiB dictionary: the executables share most of their code
    tar -C "$dir/stage" -cf - . | xz -9 -T0 >"$dir/payload.tar.xz"
    rm -rf "$dir/stage" "$dir/suites.txt"
    mkdir -p /tmp/amd64/partial
    local o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
    # shellcheck disable=SC2086
    apt-get $o update -qq
    # shellcheck disable=SC2086
    (cd "$dir/gl" && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version "$PY_TAG" \
        --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d "$dir/whl" "$SPL" numpy
    local tracked carried
    tracked=$(git ls-files -z | xargs -0 du -cb | tail -n1 | cut -f1)
    carried=$(du -sb "$dir" | cut -f1)
    ls -l "$dir" "$dir/gl" "$dir/whl"
    echo "prepare: $dir holds $carried bytes, the tracked tree $tracked: $((tracked + carried)) of $CARRY_LIMIT"
    if ((tracked + carried > CARRY_LIMIT)); then
        echo "prepare: over the device tool's 64 MiB" >&2
        exit 1
    fi
    echo "device run: carry [\"$dir\"], command: tools/gpu_machine.sh run \"\$OUT\""
}

# ---- run: helpers --------------------------------------------------------------------------
START=$SECONDS
left() { echo $((BUDGET - (SECONDS - START))); }
cap() { echo $(($1 < $2 ? ($1 > 1 ? $1 : 1) : $2)); } # min(a, b), at least 1
note() { echo "$*" | tee -a "$OUT/summary.md" >&2; }

# step NAME MIN_SECONDS CMD...: runs CMD with what is left of the budget (less a reserve for the
# steps after it) if at least MIN_SECONDS are left; its stdout, if JSON, goes into
# results.jsonl with the step's name, exit code and seconds; stderr into log.txt.
step() {
    local name=$1 min=$2 rc t0 out
    shift 2
    local budget
    budget=$(($(left) - 15))
    if ((budget < min)); then
        note "- $name: skipped ($budget s left, needs $min)"
        echo "{\"step\": \"$name\", \"skipped\": true}" >>"$OUT/results.jsonl"
        return 0
    fi
    t0=$SECONDS
    out=$(mktemp)
    echo "=== $name: $*" >>"$OUT/log.txt"
    timeout -s TERM -k 20 "$budget" "$@" >"$out" 2>>"$OUT/log.txt"
    rc=$?
    local secs=$((SECONDS - t0))
    python3 - "$name" "$rc" "$secs" "$out" >>"$OUT/results.jsonl" <<'EOF'
import json, sys
name, rc, secs, path = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
text = open(path).read()
start = text.find("{")
try:
    result = json.loads(text[start:]) if start >= 0 else None
except ValueError:
    result = None
line = {"step": name, "rc": rc, "seconds": secs, "result": result}
if result is None:
    line["stdout_tail"] = text[-4000:]
print(json.dumps(line))
EOF
    [ -s "$out" ] && { echo "--- stdout"; tail -c 20000 "$out"; } >>"$OUT/log.txt"
    rm -f "$out"
    note "- $name: rc $rc, $secs s"
    return 0
}

# The adapter nimbus opens, as JSON (a tiny `bench pbf`'s adapter_info).
probe_adapter() {
    "$NIMBUS" bench pbf --particles 8000 --steps 1 --warmup 1 2>>"$OUT/log.txt" |
        python3 -c 'import json,sys; d=json.load(sys.stdin); print(json.dumps(d["adapter_info"]))' 2>/dev/null
}

# The GPU test suites from the payload (`run`'s internal `_suites`); the executables look for
# the tree they were built in.
suites() {
    local dir=$1 root name rc
    root=$(cat "$dir/tests/root")
    if [ ! -e "$root" ]; then
        mkdir -p "$(dirname "$root")" && ln -s "$ROOT" "$root"
    fi
    # CARGO_BIN_EXE_nimbus of the tests: the debug binary there, the carried release one here
    if [ ! -e "$root/target/debug/nimbus" ]; then
        mkdir -p "$root/target/debug" && ln -sf "$NIMBUS" "$root/target/debug/nimbus"
    fi
    rc=0
    for name in ${NIMBUS_GPU_SUITES:-$SUITES_ALL}; do
        echo "--- suite $name" >&2
        "$dir/tests/$name" --test-threads="$(nproc)" >&2 || rc=1
    done
    echo "{\"suites\": \"${NIMBUS_GPU_SUITES:-$SUITES_ALL}\", \"all_passed\": $([ $rc = 0 ] && echo true || echo false)}"
    return $rc
}

# The hero shot until NIMBUS_GPU_DEADLINE less a minute (`run`'s internal `_hero`; SIGTERM:
# nimbus finishes the frame, checkpoints and exits 130), then its previews and stats into OUT.
hero() {
    local cfg=$1 dir=/tmp/nimbus-hero
    rm -rf "$dir"
    local sets=()
    for s in ${NIMBUS_GPU_HERO_SET:-}; do sets+=(--set "$s"); done
    local t=$((NIMBUS_GPU_DEADLINE - $(date +%s) - 60))
    ((t > 0)) || t=1
    # the outer step's timeout signals the whole group: this shell stays to copy the previews
    trap 'true' TERM
    timeout -s TERM -k 45 "$t" "$NIMBUS" run "$cfg" --out "$dir" --log-format json "${sets[@]}" >&2
    local rc=$?
    [ -f "$dir/stats.jsonl" ] && cp "$dir/stats.jsonl" "$OUT/hero-stats.jsonl"
    # at most 4 images back: the contact sheet if the run finished, else the first, middle
    # and last frames' previews
    local pngs=()
    mapfile -t pngs < <(find "$dir/preview" -maxdepth 1 -name '*.png' ! -name contact_sheet.png 2>/dev/null | sort)
    [ -f "$dir/preview/contact_sheet.png" ] && cp "$dir/preview/contact_sheet.png" "$OUT/hero-contact-sheet.png"
    local n=${#pngs[@]}
    if ((n > 0)); then
        for k in 0 $((n / 2)) $((n - 1)); do
            cp "${pngs[$k]}" "$OUT/hero-$(basename "${pngs[$k]}" | tr -c 'A-Za-z0-9._\n-' _)"
        done
    fi
    echo "{\"config\": \"$cfg\", \"rc\": $rc, \"frames_written\": $n, \"previews\": \"$(ls "$OUT" | grep '^hero-.*png$' | tr '\n' ' ')\"}"
    # 130: stopped at the budget after a whole frame, as planned
    [ $rc = 0 ] || [ $rc = 130 ]
}

run() {
    OUT=${1:-${OUT:-$ROOT/gpu-machine-out}}
    BUDGET=${NIMBUS_GPU_BUDGET:-540}
    export NIMBUS_GPU_DEADLINE=$(($(date +%s) + BUDGET))
    local dir=${NIMBUS_GPU_DIR:-$ROOT/.gpu-machine}
    mkdir -p "$OUT"
    : >"$OUT/log.txt"
    : >"$OUT/results.jsonl"
    local p1=${NIMBUS_GPU_PARTICLES:-1000000} p10=${NIMBUS_GPU_LARGE:-10000000}
    local warm=${NIMBUS_GPU_STEP_WARMUP:-40} cores
    cores=$(nproc)
    export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/nimbus-xdg}
    mkdir -p -m 0700 "$XDG_RUNTIME_DIR"
    {
        echo "# GPU machine run, $(date -u +%FT%TZ)"
        echo
        echo "- machine: $(uname -srm), $cores cores"
        echo "- GPU: $(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 | head -n1)"
    } >"$OUT/summary.md"

    # the payload: the binary and the suites' executables
    local unpacked=/tmp/nimbus-gpu-payload
    rm -rf "$unpacked" && mkdir -p "$unpacked"
    if ! xz -dc "$dir/payload.tar.xz" 2>/dev/null | tar -C "$unpacked" -xf - 2>/dev/null; then
        python3 -c 'import lzma,sys,tarfile; tarfile.open(fileobj=lzma.open(sys.argv[1])).extractall(sys.argv[2])' \
            "$dir/payload.tar.xz" "$unpacked" || { note "no payload in $dir: run prepare"; return 2; }
    fi
    NIMBUS=${NIMBUS:-$unpacked/bin/nimbus}
    export NIMBUS OUT
    note "- commit: $(cat "$unpacked/commit" 2>/dev/null || echo unknown) (prepared)"

    # 1. Vulkan: the loader from gl/ when the machine has none, the NVIDIA ICD from the driver.
    if [ -d "$dir/gl" ] && ! ldconfig -p | grep -q libvulkan.so.1; then
        for f in "$dir"/gl/*.deb; do dpkg -x "$f" /; done
        ldconfig
    fi
    local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json probe
    probe=$(probe_adapter)
    if ! grep -qi nvidia <<<"$probe" && [ -f "$icd" ]; then
        export VK_DRIVER_FILES=$icd
        export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
        probe=$(probe_adapter)
    fi
    echo "{\"step\": \"adapter\", \"result\": ${probe:-null}}" >>"$OUT/results.jsonl"
    if [ -z "$probe" ]; then
        note "- adapter: none (wgpu found no device; log.txt)"
        return 4
    fi
    note "- adapter: $(python3 -c 'import json,sys; d=json.loads(sys.argv[1]); print(d["name"], d["backend"], d["driver"], d["driver_info"], "subgroup", d["subgroup_size"], "limits", json.dumps(d["limits"]))' "$probe")"
    if grep -qi '"Cpu"' <<<"$probe" && [ "${NIMBUS_GPU_ALLOW_CPU:-0}" != 1 ]; then
        note "wgpu sees only a CPU adapter: the NVIDIA GPU is not visible through Vulkan; stopping"
        return 4
    fi

    # 2. The GPU suites on this adapter.
    step suites 30 "$SELF" _suites "$unpacked"
    # 3. The PBF step alone (periodic cube, docs/PERFORMANCE.md "PBF"), from rest and disordered.
    step "bench pbf $p1 warmup 1" 10 "$NIMBUS" bench pbf --particles "$p1" --steps 10 --warmup 1
    step "bench pbf $p1 warmup 30" 10 "$NIMBUS" bench pbf --particles "$p1" --steps 10 --warmup 30
    # 4. SPlisHSPlasH on every core, nimbus on the GPU, the same block scene.
    # (a venv without pip, filled by this python's pip from the carried wheels, numpy too: a
    # venv does not see the packages of a python that itself lives in a venv; SPlisHSPlasH
    # finds its models beside the venv's python, in bin/data)
    local venv=${NIMBUS_SPL_VENV:-/tmp/nimbus-splvenv}
    if [ -z "${NIMBUS_SPL_VENV:-}" ] && compgen -G "$dir/whl/pysplishsplash-*.whl" >/dev/null; then
        python3 -m venv --without-pip "$venv" &&
            PIP_ROOT_USER_ACTION=ignore python3 -m pip install -q --no-index --no-deps --prefix "$venv" "$dir"/whl/*.whl >>"$OUT/log.txt" 2>&1
    fi
    step "side by side $p1" 60 env NIMBUS_SPL_VENV="$venv" python3 tools/bench_pbf_vs_splishsplash.py \
        --nimbus "$NIMBUS" --particles "$p1" --warmups 1,30 --steps "${NIMBUS_GPU_SPL_STEPS:-10}" \
        --threads "$cores" --work /tmp/nimbus-splbench
    # 5. The full adaptive step, paper example 1 widened; then the 10M sizes, the heaviest; the
    # hero keeps two minutes (its warm-up stops in time: --max-seconds).
    local hero_cfg=${NIMBUS_GPU_HERO:-pipelines/hero_cumulus_hd.yaml} reserve=0
    [ -f "$hero_cfg" ] && reserve=120
    step "bench step $p1" 30 "$NIMBUS" bench step --particles "$p1" --frames 3 --warmup "$warm" \
        --max-seconds "$(cap $(($(left) - 40 - reserve)) 150)"
    step "bench pbf $p10" 20 "$NIMBUS" bench pbf --particles "$p10" --steps 5 --warmup 2
    step "bench step $p10" 60 "$NIMBUS" bench step --particles "$p10" --frames 2 --warmup "$warm" \
        --max-seconds "$(cap $(($(left) - 40 - reserve)) 240)"
    # 6. The hero shot of the look issue for the time left.
    if [ -f "$hero_cfg" ]; then
        step "hero $hero_cfg" 90 "$SELF" _hero "$hero_cfg"
    else
        note "- hero: skipped, $hero_cfg is not in this tree (issue 37 writes it)"
    fi

    python3 - "$OUT" >>"$OUT/summary.md" <<'EOF'
import json, sys
out = sys.argv[1]
print("\n## Figures\n")
for line in open(f"{out}/results.jsonl"):
    s = json.loads(line)
    r, name = s.get("result"), s["step"]
    if s.get("skipped") or not isinstance(r, dict):
        continue
    if name.startswith("bench pbf"):
        a = r.get("with_adaptivity", {})
        print(f"- {name}: {r['particles']} particles, PBF step {r['pbf_step_ms']:.2f} ms "
              f"({r['particles'] / r['pbf_step_ms'] / 1e3:.1f} M particle-steps/s), "
              f"{r['device_bytes_per_particle']:.1f} device bytes per particle "
              f"({a.get('device_bytes_per_particle', 0):.1f} with adaptivity)")
    elif name.startswith("bench step"):
        ms = r["ms_per_substep"]
        print(f"- {name}: {r['initial_particles']} particles ({r['final_particles']:.0f} at the "
              f"end, clouds formed: {r['clouds_formed']}), full step {r['step_ms']:.2f} ms = "
              f"PBF {ms['pbf']:.2f} + smoothing {ms['smoothing']:.2f} + cloud {ms['cloud']:.2f} "
              f"+ split {ms['split']:.2f} + merge {ms['merge']:.2f}; "
              f"{r['particle_steps_per_second'] / 1e6:.1f} M particle-steps/s, "
              f"{r['device_bytes_per_particle']:.1f} device bytes per particle")
    elif name == "suites":
        print(f"- GPU suites: all passed: {r['all_passed']} ({r['suites']})")
    elif name.startswith("hero"):
        print(f"- hero: {r}")
EOF
    # the side by side's table, as the script printed it
    awk '/^\| particles/ {on = 1} on && /^\|/ {print; next} on {exit}' "$OUT/log.txt" >>"$OUT/summary.md"
    # log.txt back under the device tool's 16 MiB a file
    if [ "$(stat -c %s "$OUT/log.txt")" -gt $((15 << 20)) ]; then
        tail -c $((15 << 20)) "$OUT/log.txt" >"$OUT/log.tmp" && mv "$OUT/log.tmp" "$OUT/log.txt"
    fi
    note "- total: $((SECONDS - START)) s"
    cat "$OUT/summary.md"
}

case "${1:-}" in
prepare) shift; prepare "$@" ;;
run) shift; run "$@" ;;
_suites) shift; suites "$@" ;;
_hero) shift; hero "$@" ;;
*)
    sed -n '2,33p' "$0" | sed 's/^# \{0,1\}//'
    exit 2
    ;;
esac
