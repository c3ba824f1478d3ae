#!/usr/bin/env bash
# Bring stages that a clone of this repository finished (tools/stages.sh running in it) back
# into this checkout: each stage's outputs copied from the clone; its lock recorded as the
# clone's entry where this checkout computes the same one (the same command, code and
# parameters), otherwise by a relock against the clone's commit, which records it only where
# both commits compute the same outputs at the rehearsal budget; and, for a training stage
# (train@, train_learner@), its zoo stage run here. Then commit dvc.lock, zoo/ and the
# git-kept outputs (an evaluation's results/evaluation/<arm>), and remove the stages from
# RERUNNING in tests/test_reproducible.py.
#
#   tools/bring_back.sh CLONE STAGE [STAGE ...]     e.g. /work/retrain train@main-dense
#   tools/bring_back.sh /work/retrain evaluate@main
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
    # Where this checkout computes the stage's lock entry as the clone did (the same
    # command, code and parameters), recording it is enough; otherwise a relock checks at
    # the rehearsal budget that the code that moved computes the same outputs.
    before=$(mktemp)  # this checkout's lock as it was (empty: none yet)
    [ ! -f dvc.lock ] || cp dvc.lock "$before"
    dvc commit --force "$stage" >/dev/null
    if python - "$stage" "$clone/dvc.lock" <<'EOF'
import sys

import yaml

stage, theirs = sys.argv[1], sys.argv[2]
ours = yaml.safe_load(open("dvc.lock"))["stages"][stage]
sys.exit(ours != yaml.safe_load(open(theirs))["stages"][stage])
EOF
    then
        how="recorded: the clone's lock entry exactly"
    else
        if [ -s "$before" ]; then cp "$before" dvc.lock; else rm -f dvc.lock; fi
        work=$(mktemp -d)
        python tools/relock.py relock "$stage" --base "$base" --work "$work"
        rm -rf "$work"
        how="relocked against $base"
    fi
    rm -f "$before"
    case "$stage" in
        train@* | train_learner@*)
            dvc repro --single-item "zoo@${stage#*@}"
            echo "brought back $stage and zoo@${stage#*@} ($how)"
            ;;
        *) echo "brought back $stage ($how)" ;;
    esac
done
