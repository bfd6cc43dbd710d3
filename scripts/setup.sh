#!/usr/bin/env bash
# Creates .venv (or $QMDF_VENV) and installs qmdf with its test tools. Safe to re-run: it does nothing when
# the environment is already up to date with pyproject.toml.
#
# torch comes first, and as a CPU build unless you say otherwise, because an unpinned `torch` from PyPI is a
# multi-GB CUDA build on Linux. For a GPU, create the venv yourself and install the torch build for your
# CUDA from PyTorch's install selector before running this script (it keeps an importable torch), or set
#   QMDF_TORCH="torch --index-url <PyTorch's CUDA wheel index>"
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${QMDF_VENV:-.venv}
PYTHON=${PYTHON:-python3}
STAMP="$VENV/.qmdf-installed"

if [ -f "$STAMP" ] && [ "$STAMP" -nt pyproject.toml ] && [ "$STAMP" -nt scripts/setup.sh ]; then
  exit 0
fi
[ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)

if ! "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
  if [ -n "${QMDF_TORCH:-}" ]; then
    # shellcheck disable=SC2086
    "${PIP[@]}" install $QMDF_TORCH
  elif ! "${PIP[@]}" install "torch==2.13.0+cpu" 2>/dev/null; then
    # No local CPU wheel: take one from PyTorch's CPU index (the CPU build is ~200 MB instead of several GB).
    "${PIP[@]}" install torch --index-url https://download.pytorch.org/whl/cpu
  fi
fi
"${PIP[@]}" install -e ".[dev]"
# compile the numba kernels now rather than inside the user's first run (qmdf/warmup.py)
"$VENV/bin/python" -m qmdf.warmup || true
touch "$STAMP"
echo "qmdf is installed in $VENV (torch $("$VENV/bin/python" -c 'import torch; print(torch.__version__)'))"
