#!/usr/bin/env bash
# Install parefg's stack on Debian 12: Debian's PETSc/MPI/HDF5/gmsh Python
# packages, then a virtual environment on Debian's python3 that sees them.
# Idempotent: installs only what is missing.
set -euo pipefail
cd "$(dirname "$0")/../.."

missing=()
for pkg in "$@"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "ok installed" || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing Debian packages: ${missing[*]}"
    sudo=""; [ "$(id -u)" -ne 0 ] && sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# The pyenv python3 first on PATH does not see Debian's packages: use /usr/bin/python3.
if [ ! -x .venv/bin/python ]; then
    /usr/bin/python3 -m venv --system-site-packages .venv
fi
# Debian's petsc4py.pth only finds petsc4py when PETSC_DIR is set (or the
# petsc-dev alternative exists); give the venv its own path entry instead.
petsc_dir=/usr/lib/petscdir/petsc3.18/x86_64-linux-gnu-real
site=$(.venv/bin/python -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
echo "$petsc_dir/lib/python3/dist-packages" > "$site/parefg-petsc4py.pth"

export PIP_CONSTRAINT="$PWD/scripts/setup/constraints.txt"
.venv/bin/pip install -q --disable-pip-version-check --no-deps -e .
.venv/bin/pip install -q --disable-pip-version-check pytest pytest-xdist hypothesis ruff mypy
.venv/bin/python -c "import parefg, petsc4py, mpi4py, h5py, gmsh, numpy; assert numpy.__version__ < '2'"
echo "setup: ok"
