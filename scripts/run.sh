#!/usr/bin/env bash
# The main job: set up and build if needed, then `frostvdb run` (built-in default scene unless a
# scene and options are given). Example: scripts/run.sh scenes/dendrite_square.toml --out out/x
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/bootstrap.sh"
cd "$here"
exec build/bin/frostvdb run "$@"
