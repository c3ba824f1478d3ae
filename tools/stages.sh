#!/usr/bin/env bash
# Run DVC stages one after another, in the background of a long session, each on its own
# (`dvc repro --single-item`), logging when each starts and ends and its wall time.
#
#   setsid nohup tools/stages.sh LOG STAGE [STAGE ...] &
#
# Run it from the root of the repository whose stages it runs (a clone may run the
# checkout's copy of this script).
#
# Stops at the first stage that fails. The log's lines "done STAGE SECONDS" are what a
# session commits (the stage's lock and its git-kept outputs). Rerun the same line after the
# session's end cut it: stages already done are skipped (DVC finds them up to date), and a
# training cut midway resumes from its last checkpoint (its command with resume=true, then
# `dvc commit`: dvc.yaml's comment on `train`), so at most `profile.checkpoint_every` steps
# per member are played again. Pause it for a benchmark or a test suite with
# `kill -STOP -- -PGID` and `kill -CONT`.
set -u
log=$1
shift

# Prints the stage's command when it is a training with a member cut midway (a checkpoint,
# no final model), and succeeds when the stage is stale too: a training the session's end
# cut. DVC's own API reads
# dvc.yaml, so foreach stages expand as `dvc repro` would expand them.
resumable() {
    python - "$1" <<'EOF'
import sys
from pathlib import Path

from dvc.repo import Repo

(stage,) = Repo().stage.collect(sys.argv[1])
folders = [Path(o.fs_path) for o in stage.outs if Path(o.fs_path).is_dir()]
# a member cut midway: a checkpoint in its run folder and no final model beside it (a
# finished training's folder keeps its checkpoint too; a stale finished stage is retrained)
cut = [s for f in folders for s in f.rglob("checkpoints/state.pkl")]
if "bgap.train" in stage.cmd and any(not (s.parent.parent / "model.zip").exists() for s in cut):
    print(stage.cmd)
EOF
    [ "$(dvc status --json "$1")" != "{}" ]  # stale: not recorded as done
}

for stage in "$@"; do
    start=$(date +%s)
    if cmd=$(resumable "$stage") && [ -n "$cmd" ]; then
        echo "resume $stage $(date -u +%FT%TZ)" >>"$log"
        # shellcheck disable=SC2086  # the stage's command, word-split as DVC's shell would
        if ! { eval "$cmd resume=true" && dvc commit --force "$stage"; } >>"$log.out" 2>&1; then
            echo "failed $stage $(( $(date +%s) - start ))" >>"$log"
            exit 1
        fi
    else
        echo "start $stage $(date -u +%FT%TZ)" >>"$log"
        if ! dvc repro --single-item "$stage" >>"$log.out" 2>&1; then
            echo "failed $stage $(( $(date +%s) - start ))" >>"$log"
            exit 1
        fi
    fi
    echo "done $stage $(( $(date +%s) - start ))" >>"$log"
done
echo "all done $(date -u +%FT%TZ)" >>"$log"
