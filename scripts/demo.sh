#!/usr/bin/env bash
# The README's first command: set-up, a Release build of `omm`, a simulated
# project in projects/demo (made once; delete it to make a new one), and
# `omm run` on it. Exits with omm's exit code, except that a stage not built
# yet (exit 3) is the expected end of the demo while the pipeline is being
# built: the script then says how far the run got and succeeds.
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
  echo "== the report: projects/demo/out/report.json (summary below; the truth is projects/demo.truth.json)"
  build/app/omm report projects/demo
elif [ $status -eq 3 ]; then
  echo "== omm ran every stage that is built so far and stopped at the first one that is not (message above)"
  if [ -e projects/demo/out/report.json ]; then
    echo "== the report of the stages that ran: projects/demo/out/report.json"
    build/app/omm report projects/demo
  fi
  exit 0
else
  echo "== omm run stopped with exit code $status (see its message above; codes: build/app/omm --help)" >&2
fi
exit $status
