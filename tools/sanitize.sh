#!/usr/bin/env bash
# Build ibrtools._core with sanitizers into its own build dir and run pytest against it,
# without touching the normal .venv install (no second editable install).
#
#   tools/sanitize.sh asan [pytest args...]   ASan + UBSan (IBR_SANITIZE=ON), build/asan
#   tools/sanitize.sh tsan [pytest args...]   ThreadSanitizer (IBR_SANITIZE_THREAD=ON), build/tsan
#
# How it runs: the sanitized _core .so is placed in build/<kind>/stage/ibrtools/ next to
# symlinks to every entry of python/ibrtools; PYTHONPATH puts the stage first, and a
# sitecustomize.py in the stage removes the .venv's editable-install finder from sys.meta_path
# (it runs after the .pth files; the finder would otherwise hand out the normal, unsanitized
# _core, whatever sys.path says). The uninstrumented Python
# interpreter needs the sanitizer runtime preloaded (LD_PRELOAD). Python leaks by design,
# so leak detection is off; every other report aborts the run (halt_on_error=1).
# Default test set: the environment variable SANITIZE_TESTS (space-separated paths) or,
# when unset, the whole tests/ directory.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
KIND=${1:?usage: tools/sanitize.sh asan|tsan [pytest args...]}
shift
VENV=${VENV:-.venv}
PY=$ROOT/$VENV/bin/python

case "$KIND" in
  asan) CMAKE_OPT="-DIBR_SANITIZE=ON"; RT=$(gcc -print-file-name=libasan.so)
        # libubsan is linked into the module and loads with it; only ASan must be first.
        export ASAN_OPTIONS="detect_leaks=0:halt_on_error=1:abort_on_error=1:strict_init_order=1:detect_stack_use_after_return=0:allocator_may_return_null=1"
        export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
        ;;
  tsan) CMAKE_OPT="-DIBR_SANITIZE_THREAD=ON"; RT=$(gcc -print-file-name=libtsan.so)
        # TBB's scheduler lives in the uninstrumented libtbb: its internal synchronisation
        # is invisible to TSan, so races between tasks are only reported for our own
        # (instrumented) code; tools/tsan.supp suppresses reports whose whole stack is in TBB.
        export TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:report_signal_unsafe=0:ignore_noninstrumented_modules=1:suppressions=$ROOT/tools/tsan.supp"
        ;;
  *) echo "tools/sanitize.sh: unknown kind '$KIND' (asan or tsan)" >&2; exit 2;;
esac
if [ ! -f "$RT" ] || [ "$RT" = "$(basename "$RT")" ]; then
  echo "tools/sanitize.sh: sanitizer runtime for $KIND not found (gcc -print-file-name gave '$RT')" >&2
  exit 2
fi

BUILD=$ROOT/build/$KIND
STAGE=$BUILD/stage
mkdir -p "$BUILD"
if [ ! -f "$BUILD/build.ninja" ]; then
  "$ROOT/$VENV/bin/cmake" -S . -B "$BUILD" -G Ninja \
    -DCMAKE_MAKE_PROGRAM="$ROOT/$VENV/bin/ninja" \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo $CMAKE_OPT \
    -DPython_EXECUTABLE="$PY" -DPython3_EXECUTABLE="$PY" -DPYTHON_EXECUTABLE="$PY" \
    -Dpybind11_DIR="$("$PY" -m pybind11 --cmakedir)" >/dev/null
fi
"$ROOT/$VENV/bin/cmake" --build "$BUILD" --target _core -j "${SANITIZE_JOBS:-2}"

# Stage: fresh symlinks each run (new modules are picked up), the sanitized .so copied in.
rm -rf "$STAGE"
mkdir -p "$STAGE/ibrtools"
for entry in "$ROOT"/python/ibrtools/*; do
  case "$(basename "$entry")" in __pycache__|_core.*) continue;; esac
  ln -s "$entry" "$STAGE/ibrtools/$(basename "$entry")"
done
cp "$BUILD"/_core.*.so "$STAGE/ibrtools/"
cat > "$STAGE/sitecustomize.py" <<'PY'
# tools/sanitize.sh: let PYTHONPATH (this stage) decide where ibrtools comes from.
import sys
sys.meta_path[:] = [f for f in sys.meta_path if not type(f).__module__.startswith("_editable_skbc_")]
PY
export PYTHONPATH="$STAGE:$ROOT/cli${PYTHONPATH:+:$PYTHONPATH}"
# libstdc++ preloaded too: the Python binary does not link it, and ASan's __cxa_throw
# interceptor, resolved when the runtime starts, otherwise finds no real __cxa_throw and aborts
# at the first C++ exception ("CHECK failed: real___cxa_throw != 0").
export LD_PRELOAD="$RT $(gcc -print-file-name=libstdc++.so)"
export IBR_SANITIZER="$KIND"   # lets tests know (e.g. to skip subprocess-heavy cases)
# Check the stage is what gets imported before spending time on the suite.
"$PY" -c "import ibrtools._core as c, sys; p = c.__file__; sys.exit(0 if p.startswith('$STAGE') else 'sanitize.sh: imported ' + p + ', not the staged module')"
# Reports also go to files (log_path; one per process, suffix = pid): a pytest-xdist worker that a
# report halts shows up only as "node down", its stderr is not forwarded.
REPORTS=$BUILD/reports
rm -rf "$REPORTS"
mkdir -p "$REPORTS"
case "$KIND" in
  asan) export ASAN_OPTIONS="$ASAN_OPTIONS:log_path=$REPORTS/asan"
        export UBSAN_OPTIONS="$UBSAN_OPTIONS:log_path=$REPORTS/ubsan";;
  tsan) export TSAN_OPTIONS="$TSAN_OPTIONS:log_path=$REPORTS/tsan";;
esac
TESTS=${SANITIZE_TESTS:-tests}
status=0
# shellcheck disable=SC2086
"$PY" -m pytest -q -p no:cacheprovider $TESTS "$@" || status=$?
if compgen -G "$REPORTS/*" >/dev/null; then
  for f in "$REPORTS"/*; do
    echo "=== sanitizer report: $f" >&2
    cat "$f" >&2
  done
  echo "tools/sanitize.sh: $(ls "$REPORTS" | wc -l) sanitizer report file(s) in $REPORTS" >&2
  [ "$status" -ne 0 ] || status=1
else
  echo "tools/sanitize.sh: no $KIND reports" >&2
fi
exit "$status"
