#!/usr/bin/env bash
# Run the calibration tests against another OpenCV than the pinned one.
#
#   bash scripts/check_opencv.sh 4.14.0.94 [pytest arguments, default tests/calib -m "not slow"]
#
# pyproject.toml allows a range of opencv-contrib-python-headless; requirements.lock pins one.
# This makes a throwaway virtual environment outside the repository (under ${TMPDIR:-/tmp})
# that sees every package of .venv but installs the given OpenCV over it, then runs the tests
# there. Check the newest allowed 4.x (pip index versions opencv-contrib-python-headless) and
# the oldest before changing the range (docs/calibration.md, "OpenCV versions").
set -euo pipefail
cd "$(dirname "$0")/.."
version="${1:?usage: scripts/check_opencv.sh OPENCV_VERSION [pytest args]}"
shift
root="$(pwd)"
site="$("$root/.venv/bin/python" -c 'import site; print(site.getsitepackages()[0])')"
venv="${TMPDIR:-/tmp}/sea3d-opencv-$version"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
    pyver="$("$venv/bin/python" -c 'import sys; print(f"python{sys.version_info[0]}.{sys.version_info[1]}")')"
    # Packages of .venv come after the throwaway environment's own, so its cv2 wins.
    echo "import site; site.addsitedir('$site')" > "$venv/lib/$pyver/site-packages/zz_sea3d.pth"
    "$venv/bin/pip" install --quiet --no-deps "opencv-contrib-python-headless==$version"
fi
"$venv/bin/python" -c 'import cv2; print("OpenCV", cv2.__version__, "from", cv2.__file__)'
if [ "$#" -eq 0 ]; then
    set -- tests/calib -m "not slow"
fi
exec "$venv/bin/python" -m pytest -q -p no:cacheprovider "$@"
