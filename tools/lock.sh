#!/usr/bin/env bash
# Rewrite requirements/lock.txt, the exact version of every dependency (all extras but the
# benchmark's EnvPool) that the README's set-up commands install from (pip's -c). Run after
# changing pyproject.toml's dependencies, then rerun the tests and the README's main job.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m venv /tmp/bgap-pip-tools && /tmp/bgap-pip-tools/bin/pip install -q pip-tools
/tmp/bgap-pip-tools/bin/pip-compile -q --strip-extras --no-emit-index-url --no-emit-find-links \
  --extra dev --extra cluster --extra docs --extra sumo -o requirements/lock.txt pyproject.toml
