#!/usr/bin/env bash
# Bring training stages that a clone of this repository finished (tools/stages.sh running in
# it, sharing this checkout's DVC cache) back into this checkout: each stage's outputs copied
# from the clone, its lock recorded by a relock against the clone's commit (the code here
# moved since; the relock records it only where both commits compute the same outputs at the
# rehearsal budget), and its zoo stage run here. Then commit dvc.lock and zoo/, and remove
# the stages from RERUNNING in tests/test_reproducible.py.
#
#   tools/bring_back.sh CLONE STAGE [STAGE ...]     e.g. /work/retrain train@main-dense
set -euo pipefail
clone=$(cd "$1" && pwd)
shift
base=$(git -C "$clone" rev-parse HEAD)
cd "$(dirname "$0")/.."
for stage in "$@"; do
    outs=$(python - "$stage" <<'EOF'
import sys

from dvc.repo import Repo

(stage,) = Repo().stage.collect(sys.argv[1])
print("\n".join(str(o.def_path) for o in stage.outs))
EOF
    )
    if [ "$(cd "$clone" && dvc status --json "$stage")" != "{}" ]; then
        echo "bring_back.sh: $stage is not done in $clone (dvc status there); finish it first" >&2
        exit 2
    fi
    for out in $outs; do
        rm -rf "$out"
        mkdir -p "$(dirname "$out")"
        cp -r "$clone/$out" "$out"
    done
    work=$(mktemp -d)
    python tools/relock.py relock "$stage" --base "$base" --work "$work"
    rm -rf "$work"
    dvc repro --single-item "zoo@${stage#*@}"
    echo "brought back $stage and zoo@${stage#*@} (relocked against $base)"
done
