#!/usr/bin/env bash
# The README's main job: install, then run the streaming demo pipeline
# (simulator -> cDFCVAE translator with the shipped checkpoint -> recorder) and say where results are.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet torch==2.13.0 -e .
sonar-realism launch launch/demo.toml "$@"
