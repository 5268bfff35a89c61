#!/usr/bin/env bash
# Set up and build if needed, then run the whole test suite through ctest.
# Tests tagged [slow] are skipped unless FROSTVDB_SLOW=1.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$here/scripts/bootstrap.sh"
cd "$here/build"
exec ctest --output-on-failure -j "$(nproc 2>/dev/null || echo 2)" "$@"
