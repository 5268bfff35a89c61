#!/usr/bin/env bash
# Builds and runs the libFuzzer harnesses of fuzz/ (docs/fuzzing.md).
#   scripts/fuzz.sh [SECONDS]            the scene and PNG harnesses for SECONDS in total (default
#                                        60: scene 40, png 20); exit 1 on any crash. The VDB harness
#                                        joins (scene 1/2, png 1/4, vdb 1/4) with FROSTVDB_FUZZ_VDB=1:
#                                        it is off by default because OpenVDB's reader allocates
#                                        the lengths a damaged file claims (docs/fuzzing.md)
#   scripts/fuzz.sh --runs N [TARGET]    TARGET (scene|png|vdb, default scene) for N executions
# Installs its own packages (clang and libclang-rt-14-dev, which ships libclang_rt.fuzzer), builds
# the instrumented library into build-fuzz/ (clang, -fsanitize=fuzzer-no-link,address; the gcc
# build in build/ is untouched), seeds the corpora from scenes/ and generated maps, and keeps
# crashing inputs in build-fuzz/crashes/ (turn each into a file under tests/fuzz_regressions/).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"

packages=(clang libclang-rt-14-dev)
"$here/scripts/install-packages.sh" "${packages[@]}"

b=build-fuzz
t0=$(date +%s)
if [ ! -f $b/CMakeCache.txt ]; then
  # -O0: the fastest compile (the library is big and the harnesses mostly parse); ASan checks it
  CC=clang CXX=clang++ cmake -S . -B $b -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS_RELEASE="-O0 -DNDEBUG" \
    -DFROSTVDB_FUZZ=ON >&2
fi
jobs="${FROSTVDB_JOBS:-$(nproc 2>/dev/null || echo 2)}"
cmake --build $b -j "$jobs" >&2
echo "fuzz: build took $(( $(date +%s) - t0 )) s" >&2

# Corpora: the shipped scenes and every regression input; generated PNG/VDB maps.
mkdir -p $b/corpus/scene $b/corpus/png $b/corpus/vdb $b/crashes
cp scenes/*.toml $b/corpus/scene/
for k in scene png; do # (the vdb regressions are known OpenVDB over-allocations: not seeds)
  [ -d tests/fuzz_regressions/$k ] && cp tests/fuzz_regressions/$k/* $b/corpus/$k/ 2>/dev/null || true
done
ASAN_OPTIONS=detect_leaks=0 $b/bin/frostvdb_fuzz_seeds $b/corpus/png $b/corpus/vdb >/dev/null
# Dictionary: every section and key of the scene reference, plus TOML punctuation.
{
  printf '"["\n"]"\n"[["\n"]]"\n" = "\n"true"\n"false"\n"1e308"\n"-1"\n"0"\n"nan"\n"inf"\n'
  grep -o '^## \[[a-z_0-9]*\]' docs/scene-reference.md | sed 's/^## //; s/.*/"&"/'
  grep -oE '^\| `[^`]+`' docs/scene-reference.md | sed -E 's/^\| `//; s/`$//; s/.*\]\.//' | sort -u | sed 's/.*/"&"/'
} > $b/scene.dict

run() { # target seconds-or-empty runs-or-empty
  local target=$1 secs=$2 runs=$3 extra=()
  [ "$secs" = 0 ] && return 0
  [ "$target" = scene ] && extra+=(-dict=$b/scene.dict)
  [ -n "$secs" ] && extra+=(-max_total_time="$secs")
  [ -n "$runs" ] && extra+=(-runs="$runs")
  echo "fuzz: $target ${secs:+for $secs s}${runs:+for $runs runs}" >&2
  # leaks: OpenVDB's registries are process-lifetime; a leak is not what we hunt here
  ASAN_OPTIONS=detect_leaks=0:allocator_may_return_null=0 \
    $b/bin/frostvdb_fuzz_$target "${extra[@]}" -timeout=30 -rss_limit_mb=2048 -max_len=65536 \
      -artifact_prefix=$b/crashes/$target- -print_final_stats=1 $b/corpus/$target 2>&1 |
    grep -E "^(#[0-9]+ *(DONE|INITED)|stat::|==[0-9]+== ?ERROR|SUMMARY|artifact_prefix|Test unit written|frostvdb fuzz)"
  # the fuzzer's own status (read at once: a `|| true` here used to reset PIPESTATUS, so that
  # with pipefail a failing fuzzer, a timeout or a crash, still returned 0)
  local codes=("${PIPESTATUS[@]}")
  return "${codes[0]}"
}

if [ "${1:-}" = "--runs" ]; then
  run "${3:-scene}" "" "$2"
  exit $?
fi
total="${1:-60}"
status=0
if [ "${FROSTVDB_FUZZ_VDB:-0}" = 1 ]; then
  run scene $(( total / 2 )) "" || status=1
  run png $(( total / 4 )) "" || status=1
  run vdb $(( total - total / 2 - total / 4 )) "" || status=1
else
  run scene $(( total * 2 / 3 )) "" || status=1
  run png $(( total - total * 2 / 3 )) "" || status=1
fi
if [ $status -ne 0 ]; then
  echo "fuzz: crashes in $b/crashes/ (see docs/fuzzing.md: each becomes a regression test)" >&2
fi
exit $status
