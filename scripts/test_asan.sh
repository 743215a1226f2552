#!/usr/bin/env bash
# The C++ tests built once with AddressSanitizer + UndefinedBehaviorSanitizer (`make test-asan`):
# plain cmake of the top-level CMakeLists (no Python module) in build/asan, then ctest there. Any
# sanitizer report fails the test that triggered it (UBSan does not recover, ASan aborts).
set -eo pipefail
cd "$(dirname "$0")/.."
BUILD=${ASAN_BUILD_DIR:-build/asan}
SAN="-fsanitize=address,undefined -fno-sanitize-recover=all -fno-omit-frame-pointer"
# Eigen stops trusting malloc's alignment under ASan and frees with its own offset header, but the
# Debian PCL libraries (built without ASan) allocate Eigen-aligned clouds with plain malloc: a
# cloud allocated in PCL and freed in our code then looks like a heap overflow. Tell Eigen what
# holds on 64-bit glibc (and under ASan): malloc is 16-byte aligned, as in PCL's own build.
SAN_DEFS="-DEIGEN_MALLOC_ALREADY_ALIGNED=1"
export CMAKE_CXX_COMPILER_LAUNCHER=${CMAKE_CXX_COMPILER_LAUNCHER:-ccache}
cmake -S . -B "$BUILD" -G Ninja -DBUILD_TESTING=ON -DBUILD_PYTHON=OFF -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g" -DCMAKE_CXX_FLAGS="$SAN $SAN_DEFS" \
  -DCMAKE_EXE_LINKER_FLAGS="$SAN" -DCMAKE_SHARED_LINKER_FLAGS="$SAN" >/dev/null
# gtest discovery runs the test binaries at build time: the same options as ctest below.
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
cmake --build "$BUILD" -j"${JOBS:-2}"
ctest --test-dir "$BUILD" --output-on-failure --no-tests=error -j"${JOBS:-2}"
