#!/usr/bin/env bash
# Whether two builds of nimbus write the same run directories: the check every refactoring step
# of the house passes (docs/ARCHITECTURE.md "Layers").
#   tools/byte_identical.sh BIN_BEFORE BIN_AFTER [WORK_DIR]
# Runs quickstart (48 frames), paper example 1 at half width (40 frames) and paper example 2
# (60 frames) with each binary into the same path (the manifest records it), hashes every file
# with tools/run_hashes.py (stats.jsonl without phase_ms) and compares. Exit 0 when all three
# are identical, 1 otherwise (the differing files are printed). About 6 minutes per binary on
# 2 cores.
set -euo pipefail
[[ $# -ge 2 ]] || { echo "usage: $0 BIN_BEFORE BIN_AFTER [WORK_DIR]" >&2; exit 2; }
before=$(realpath "$1") after=$(realpath "$2") work=${3:-/tmp/nimbus-byte-identical}
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/nimbus-xdg}
mkdir -p "$XDG_RUNTIME_DIR" "$work" && chmod 700 "$XDG_RUNTIME_DIR"
shots=(
  "quickstart pipelines/quickstart.yaml"
  "example1_half pipelines/paper_example1.yaml --set domain.size=[1600,1600,1600] --set output.frames.end=40"
  "example2 pipelines/paper_example2.yaml --set output.frames.end=60"
)
status=0
set -f  # the --set values hold brackets
for shot in "${shots[@]}"; do
  read -r name args <<< "$shot"
  for side in before after; do
    bin=$before; [[ $side == after ]] && bin=$after
    rm -rf "$work/out"
    start=$SECONDS
    # shellcheck disable=SC2086
    "$bin" run $args --out "$work/out" > "$work/$name.$side.log" 2>&1
    python3 tools/run_hashes.py "$work/out" > "$work/$name.$side.sha"
    echo "$name, $side: $((SECONDS - start)) s, $(wc -l < "$work/$name.$side.sha") files" >&2
  done
  if cmp -s "$work/$name.before.sha" "$work/$name.after.sha"; then
    echo "$name: identical ($(wc -l < "$work/$name.before.sha") files)"
  else
    echo "$name: DIFFERENT"
    diff "$work/$name.before.sha" "$work/$name.after.sha" || true
    status=1
  fi
done
exit $status
