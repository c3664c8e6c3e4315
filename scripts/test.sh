#!/usr/bin/env bash
# Sets everything up on a fresh Debian 12 machine and runs every test tier:
#   1. cppcheck over the sources
#   2. an ASan+UBSan build running the unit, numeric, hard and fuzz tiers,
#      the cheap daemon integration tests (label daemon) and the CLI's
#      bad-input runs (label cli_errors: augment, targets, fit, model)
#   3. short libFuzzer runs (clang) over each fuzz target
#   4. the release build (-O2, -Werror)
#   5. the VM tier (ctest -L vm): qemu TCG boots Debian 12's kernel with
#      vivid and v4l2loopback around `gazesplat live`, then with the host's
#      systemd as PID 1 and the installed package (tests/vm)
#   6. every other tier in the release build; its ctest summary ends the
#      output.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
# The real-face test photos (npm); the face tests skip only without them.
scripts/fetch-test-assets.sh

echo "== cppcheck"
cppcheck --quiet --error-exitcode=1 --std=c11 --inline-suppr \
  --enable=warning,performance,portability \
  --suppress=missingIncludeSystem \
  -I lib/include -I proto lib clients daemon proto

echo "== ASan+UBSan build: unit, numeric, hard, fuzz, daemon and cli_errors tiers"
scripts/build.sh build-asan -DCMAKE_BUILD_TYPE=Debug -DGS_SANITIZE=ON
(cd build-asan && ctest --output-on-failure -j2 -L 'unit|numeric|hard|fuzz|daemon|cli_errors')

if [ -x scripts/fuzz.sh ]; then
  echo "== libFuzzer runs"
  scripts/fuzz.sh build-fuzz "${GS_FUZZ_SECONDS:-15}"
fi

echo "== release build"
scripts/build.sh build -DCMAKE_BUILD_TYPE=Release

echo "== VM tier: qemu (TCG), vivid -> gazesplat live -> v4l2loopback"
(cd build && ctest --output-on-failure -L vm)

echo "== release build: all other tiers"
cd build && ctest --output-on-failure -j2 -LE vm
