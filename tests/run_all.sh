#!/usr/bin/env bash
# The whole test suite: C++ unit tests under ctest, then pytest.
# Expects `bash .ci/setup` to have run: it creates .venv and builds the C++
# core in build/release. The ctest suite is added to that tree here (only the
# test files compile, once); later runs bring it up to date, a no-op unless C++
# changed. Without it, a build/ctest tree is configured and built here.
set -uo pipefail
cd "$(dirname "$0")/.."
py=.venv/bin/python
[ -x "$py" ] || py=python3

build=build/release
if [ -f "$build/CMakeCache.txt" ]; then
  grep -q '^GPSINS_BUILD_TESTS:BOOL=ON' "$build/CMakeCache.txt" || cmake -S . -B "$build" -DGPSINS_BUILD_TESTS=ON >/dev/null || exit 1
else
  build=build/ctest
  cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release -DGPSINS_BUILD_TESTS=ON \
    -DGPSINS_BUILD_PYTHON=ON -DPython_EXECUTABLE="$("$py" -c 'import sys; print(sys.executable)')" \
    -Dpybind11_DIR="$("$py" -m pybind11 --cmakedir)" -DGPSINS_WERROR="${GPSINS_WERROR:-OFF}" >/dev/null || exit 1
fi
cmake --build "$build" -j 2 || exit 1
ctest --test-dir "$build" --output-on-failure -j 2
ctest_rc=$?
# CMake's doctest discovery turns each case into a ctest test by name; a name it cannot
# pass back (a ';' splits it) becomes tests that match no case and pass without running.
# So the number of ctest tests must be the number of cases the binary lists.
cases=$("$build/cpp/tests/gpsins_cpp_tests" --list-test-cases --no-version 2>/dev/null | sed -n "s/.*passing the current filters: \([0-9]*\).*/\1/p")
tests=$(ctest --test-dir "$build" -N | sed -n 's/^Total Tests: *//p')
if [ "${cases:-0}" -eq 0 ] || [ "$cases" != "$tests" ]; then
  echo "ctest runs $tests tests but the C++ test binary has $cases cases: a case name did not survive discovery"
  ctest_rc=1
fi

# Two workers (the 2-core target), each test file whole on one (its module fixtures computed once):
# 9.7 min serial, 5.5 min so on the 2-core machine.
"$py" -m pytest -q -n 2 --dist loadfile "$@"
pytest_rc=$?
[ "$pytest_rc" -eq 5 ] && pytest_rc=0  # no tests collected is not a failure of the suite

[ "$ctest_rc" -eq 0 ] && [ "$pytest_rc" -eq 0 ]
