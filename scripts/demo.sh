#!/usr/bin/env bash
# The README's first command: set-up, a Release build of `omm`, a simulated
# project in projects/demo (made once; delete it to make a new one), and
# `omm run` on it, then the report's summary. Exits with omm's exit code.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build -j "${OMM_JOBS:-2}" --target omm

if [ ! -e projects/demo/project.yaml ]; then
  echo "== omm simulate projects/demo"
  build/app/omm simulate projects/demo --seed 1
fi

echo "== omm run projects/demo"
status=0
build/app/omm run projects/demo || status=$?
if [ $status -eq 0 ]; then
  echo "== the report: projects/demo/out/report.json and report.html (the truth is projects/demo.truth.json)"
  build/app/omm report projects/demo
else
  echo "== omm run stopped with exit code $status (see its message above; codes: build/app/omm --help)" >&2
fi
exit $status
