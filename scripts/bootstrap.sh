#!/usr/bin/env bash
# Creates .venv beside the repository and installs lastmile into it (editable), once per change of
# pyproject.toml. Sourced by run.sh and test.sh so that each quick-start command sets itself up.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
extras="${1:-}"
py="${PYTHON:-python3}"
if ! "$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
  echo "lastmile needs Python 3.11 or newer; '$py' is $("$py" --version 2>&1)" >&2
  exit 1
fi
stamp="$venv/.installed-$(sha256sum "$root/pyproject.toml" | cut -c1-16)${extras:+-$extras}"
if [ ! -f "$stamp" ]; then
  [ -x "$venv/bin/python" ] || "$py" -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --upgrade pip
  "$venv/bin/python" -m pip install --quiet -e "$root${extras:+[$extras]}"
  # Compile the perception and simulator kernels into the user's cache now, once per install, so the first LiDAR
  # frame of the first run takes well under a second instead of the compilation's 10-20 s. A kernel
  # it could not reach is compiled at its first call instead: said, not fatal to the install.
  OPENBLAS_NUM_THREADS=1 "$venv/bin/python" -m lastmile.perception.warmup \
    || echo "bootstrap: the perception warm-up did not compile every kernel (see above)" >&2
  OPENBLAS_NUM_THREADS=1 "$venv/bin/python" -m lastmile.sim.lidar_warmup \
    || echo "bootstrap: the simulator warm-up did not compile every kernel (see above)" >&2
  touch "$stamp"
fi
export PATH="$venv/bin:$PATH"
# One BLAS thread: small matrices in the loop get slower, not faster, with competing threads.
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
