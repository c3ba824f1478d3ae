#!/usr/bin/env bash
# Run DVC stages one after another, in the background of a long session, each on its own
# (`dvc repro --single-item`), logging when each starts and ends and its wall time.
#
#   setsid nohup tools/stages.sh LOG STAGE [STAGE ...] &
#
# Stops at the first stage that fails. The log's lines "done STAGE SECONDS" are what a
# session commits (the stage's lock and its git-kept outputs); a stage cut by the machine's
# end is rerun from its start (a training's own resume: dvc.yaml's comment on `train`).
# Pause it for a benchmark or a test suite with `kill -STOP -- -PGID` and `kill -CONT`.
set -u
log=$1
shift
for stage in "$@"; do
    start=$(date +%s)
    echo "start $stage $(date -u +%FT%TZ)" >>"$log"
    if ! dvc repro --single-item "$stage" >>"$log.out" 2>&1; then
        echo "failed $stage $(( $(date +%s) - start ))" >>"$log"
        exit 1
    fi
    echo "done $stage $(( $(date +%s) - start ))" >>"$log"
done
echo "all done $(date -u +%FT%TZ)" >>"$log"
