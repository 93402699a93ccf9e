#!/usr/bin/env bash
# The Makefile's set-up of .venv: `tools/setup_venv.sh check` prints FORCE when .venv needs (re)installing;
# `tools/setup_venv.sh install PYTHON OPEN3D` makes it where it is not whole and installs pcreg in it.
# A venv is not relocatable (its scripts name its folder): one made in another folder (a copied or moved checkout,
# whose scripts run the other checkout's code), one stopped before pip was in it, or one whose Python is gone is
# made again. Two set-ups at once wait for each other (flock); the second finds the work done.
set -euo pipefail
venv=.venv
here="$(pwd -P)/$venv"

whole() {  # made here (its own note of where), and its Python runs with pip
  [ "$(cat "$venv/.pcreg-venv" 2>/dev/null)" = "$here" ] && "$venv/bin/python" -c 'import pip' >/dev/null 2>&1
}

installed() {  # and pcreg is installed in it (-I: not the checkout's folder on the path)
  whole && "$venv/bin/python" -I -c 'import pcreg' >/dev/null 2>&1
}

case "${1:-}" in
  check)
    installed || echo FORCE ;;
  install)
    python=$2 open3d=$3 stamp="$venv/.pcreg-installed-$3"
    exec 9>"$venv.lock"
    flock 9
    if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ] && installed; then
      exit 0  # another set-up did it while this one waited
    fi
    if ! whole; then
      [ ! -e "$venv" ] || echo "making $venv again (half made, made in another folder, or its Python is gone)"
      "$python" -m venv --clear "$venv"
      echo "$here" > "$venv/.pcreg-venv"
    fi
    rm -f "$venv"/.pcreg-installed-*
    "$venv/bin/python" -m pip install -q --upgrade pip
    # the other Open3D build owns the same files: it goes first (OPEN3D=cuda, then cpu again)
    "$venv/bin/python" -m pip uninstall -q -y "$([ "$open3d" = cuda ] && echo open3d-cpu || echo open3d)" >/dev/null 2>&1 || true
    "$venv/bin/python" -m pip install -q -e ".[$open3d,test,crosscheck,distributed,lint,docs]"
    "$venv/bin/python" -m pip install -q --no-deps "probreg>=0.3.6"  # it declares the full open3d wheel; open3d-cpu serves
    touch "$stamp" ;;
  *)
    echo "usage: tools/setup_venv.sh check | install PYTHON OPEN3D" >&2
    exit 2 ;;
esac
