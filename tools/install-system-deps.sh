#!/usr/bin/env bash
# Installs the Debian/Ubuntu packages ibrtools needs to build and run, and nothing that is
# already there: Embree, TBB and GLM (C++), libusb (open3d-cpu's libOpen3D links it), Chromium's
# headless shell (tests of the HTML reports), and,
# only when missing, a C++ compiler, the Python headers and venv for $PYTHON.
# Uses apt-get when root, sudo otherwise; else prints the command and exits with 2.
set -euo pipefail
PYTHON=${PYTHON:-python3}
pkgs=(libembree-dev libtbb-dev libglm-dev libusb-1.0-0)
# The headless browser the HTML-report test opens the page in (the test skips, with the reason, without it).
pkgs+=(chromium-headless-shell)
command -v g++ >/dev/null 2>&1 || pkgs+=(g++)
command -v make >/dev/null 2>&1 || pkgs+=(make)
if ! "$PYTHON" -c 'import sysconfig, os, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'; then
  pkgs+=(python3-dev)
fi
"$PYTHON" -c 'import ensurepip, venv' >/dev/null 2>&1 || pkgs+=(python3-venv)

missing=()
for p in "${pkgs[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0

if [ "$(id -u)" = 0 ]; then sudo=""
elif command -v sudo >/dev/null 2>&1; then sudo="sudo"
else
  echo "ibrtools: missing Debian packages; install them with: sudo apt-get install ${missing[*]}" >&2
  exit 2
fi
echo "ibrtools: installing ${missing[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}"
