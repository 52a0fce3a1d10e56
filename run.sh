#!/usr/bin/env bash
# Quick start 1/2: set up (first time only) and run the default shuttle service. Extra arguments go to
# `lastmile run`, e.g. ./run.sh --minutes 3 --weather snow
set -euo pipefail
cd "$(dirname "$0")"
source scripts/bootstrap.sh
exec lastmile run "$@"
