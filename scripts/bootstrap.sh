#!/usr/bin/env bash
# Set up weldcell from nothing and run one of its two jobs.
#   scripts/bootstrap.sh demo   - detect the seams of the bundled sample capture
#   scripts/bootstrap.sh test   - lint, type-check and run the whole test suite
# Idempotent: a second run reuses .venv unless pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."
job="${1:-demo}"

say() { printf '\033[1m[weldcell setup]\033[0m %s\n' "$*" >&2; }

# open3d needs the system library libusb-1.0 (Debian package libusb-1.0-0).
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    if [ "$(id -u)" = 0 ]; then
        say "installing libusb-1.0-0 (needed by open3d)"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
    elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
        say "installing libusb-1.0-0 with sudo (needed by open3d)"
        sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
    else
        say "open3d needs libusb-1.0: run 'apt-get install libusb-1.0-0' as root, then run this again"
        exit 1
    fi
fi

PY="${PYTHON:-}"
if [ -z "$PY" ]; then
    for cand in python3.13 python3.12 python3.11 python3; do
        # pyenv shims answer `command -v` for versions that are not selected, then fail loudly when run
        if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
            PY="$cand"; break
        fi
    done
fi
[ -n "$PY" ] || { say "Python 3.11 or newer is required"; exit 1; }

# pip -qq: errors only. Plain -q still prints a warning for every configured index location that lacks a
# package (a machine's pip.conf may list local mirrors) and setuptools' notes on editable installs, pages of
# them on a first run. WELDCELL_SETUP_VERBOSE=1 shows pip's full output.
if [ -n "${WELDCELL_SETUP_VERBOSE:-}" ]; then PIP_Q=(); else PIP_Q=(-qq); fi
pip_install() { .venv/bin/python -m pip install "${PIP_Q[@]}" "$@"; }

stamp_want="$( (cat pyproject.toml constraints.txt; "$PY" --version) | sha256sum | cut -c1-16)"
if [ ! -x .venv/bin/python ] || [ "$(cat .venv/.setup-stamp 2>/dev/null)" != "$stamp_want" ]; then
    t0=$SECONDS
    if [ -x .venv/bin/python ]; then
        say "pyproject.toml or constraints.txt changed: updating .venv"
    else
        say "creating .venv with $("$PY" --version)"
        "$PY" -m venv .venv
    fi
    pip_install --upgrade 'pip>=24,<27'
    say "installing weldcell and its dependencies within constraints.txt (about a minute the first time)"
    pip_install -c constraints.txt -e '.[dev]'
    echo "$stamp_want" > .venv/.setup-stamp
    say "ready in $((SECONDS - t0)) s: $(.venv/bin/weldcell --version), $(.venv/bin/python -c \
        'import cv2, open3d, numpy; print(f"OpenCV {cv2.__version__}, Open3D {open3d.__version__}, NumPy {numpy.__version__}")')"
fi
# the detector's compiled kernels (numba): compiled once here (about 10 s the first time), then each run loads
# them from numba's cache instead of compiling them in its first detection
.venv/bin/python -c 'from perception.fine.compiled import warm_up; warm_up()'

case "$job" in
    demo)
        mkdir -p out
        exec .venv/bin/weldcell demo --out out
        ;;
    test)
        # The operator page's browser test (tests/cell/test_operator_page.py) drives Debian's Chromium through
        # Playwright (which downloads no browser of its own). Installed here for the test job only, as root (CI
        # is); without it that test is skipped and says why. About 50 s and 110 MB of packages the first time.
        if ! command -v chromium >/dev/null; then
            if [ "$(id -u)" = 0 ]; then
                say "installing chromium for the operator page's browser test"
                { apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
                    apt-get install -y -qq --no-install-recommends chromium >/dev/null; } \
                    || say "could not install chromium: the browser test will be skipped"
            else
                say "chromium is not installed: the operator page's browser test will be skipped (apt-get install chromium)"
            fi
        fi
        say "ruff"
        .venv/bin/ruff check .
        say "mypy"
        .venv/bin/mypy cell drivers perception calibration sim_fakes
        # on every core the machine gives this process (WELDCELL_TEST_WORKERS overrides), a file at a time per
        # worker: a file's module-scoped fixtures (the UR cell of test_runner, the zoo cache) are set up once, and
        # tests/conftest.py puts the slowest files first so that no worker is left alone with one at the end
        workers="${WELDCELL_TEST_WORKERS:-$(nproc 2>/dev/null || echo 2)}"
        say "pytest on $workers workers"
        exec .venv/bin/python -m pytest -q -p no:cacheprovider -n "$workers" --dist loadfile --no-loadscope-reorder
        ;;
    *)
        say "unknown job '$job': use 'demo' or 'test'"; exit 2
        ;;
esac
