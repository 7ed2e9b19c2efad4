#!/usr/bin/env bash
# The README's test command: install (CPU torch wheel pinned), lint, run the suite.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet torch==2.13.0 -e ".[dev]"
python -m ruff check .
python -m pytest -q
