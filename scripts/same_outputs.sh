#!/usr/bin/env bash
# Compare what the offline commands write at two revisions, byte for byte: a move or a split of
# code (no behaviour change) must leave them identical.
#   bash scripts/same_outputs.sh BASE [HEAD]     e.g. bash scripts/same_outputs.sh main~5
# HEAD defaults to the working tree. Runs `register --json --loo` and `plan --json` on the example
# cells (examples/cell3d, examples/plate2d), each revision from a git worktree with the venv's Python (scripts/bootstrap.sh first). Exits 1 and
# names the files that differ.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="$ROOT/.venv/bin/python"
BASE="${1:?usage: same_outputs.sh BASE [HEAD]}"
WORK="$(mktemp -d)"
trap 'git -C "$ROOT" worktree remove --force "$WORK/base" >/dev/null 2>&1 || true;
      [ -d "$WORK/head" ] && git -C "$ROOT" worktree remove --force "$WORK/head" >/dev/null 2>&1;
      rm -rf "$WORK"' EXIT
git -C "$ROOT" worktree add -q --detach "$WORK/base" "$BASE"
TREES=("base:$WORK/base")
if [ -n "${2:-}" ]; then
  git -C "$ROOT" worktree add -q --detach "$WORK/head" "$2"
  TREES+=("head:$WORK/head")
else
  TREES+=("head:$ROOT")
fi
EX="$ROOT/examples"
for entry in "${TREES[@]}"; do
  name="${entry%%:*}"; tree="${entry#*:}"; out="$WORK/out.$name"; mkdir -p "$out"
  run() { (cd "$out" && PYTHONPATH="$tree" "$PY" -c \
    'import sys; from rbc_registration.cli import main; sys.exit(main(sys.argv[1:]))' "$@" \
    >/dev/null); }
  for cell in cell3d plate2d; do
    run register "$EX/$cell/fiducials.csv" --targets "$EX/$cell/targets.csv" --loo \
      --json "$out/register_$cell.json"
    run plan "$EX/$cell/fiducials.csv" --candidates "$EX/$cell/candidates.csv" \
      --targets "$EX/$cell/targets.csv" --count 5 --json "$out/plan_$cell.json"
  done
done
status=0
for f in "$WORK/out.base"/*; do
  if cmp -s "$f" "$WORK/out.head/$(basename "$f")"; then echo "same: $(basename "$f")"
  else echo "DIFFERENT: $(basename "$f")"; status=1; fi
done
exit "$status"
