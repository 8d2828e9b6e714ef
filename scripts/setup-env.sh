# Sourced by ./run-tests and ./run-demo: create .venv with Python >= 3.11 and install
# pipestitch (editable, versions from constraints.txt, by uv or else pip; with the test
# extras for ./run-tests) when pyproject.toml or constraints.txt changed since the last
# install, or the test extras are wanted and missing; then write the package's
# bytecode, and compile the numba kernels into their cache when they changed since the
# last compile.
PY=""
for cand in python3.11 python3.12 python3.13 python3 python; do
  if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then
    PY="$cand"; break
  fi
done
if [ -z "$PY" ]; then
  echo "error: Python 3.11 or newer is needed (python3.11 not found)" >&2
  exit 2
fi
if [ ! -x .venv/bin/python ]; then
  echo "setting up .venv with $PY ..." >&2
  # without pip for now (ensurepip: ~6 s): uv installs it with the rest, below
  "$PY" -m venv --without-pip .venv
fi
# The stamp holds the hash of pyproject.toml and constraints.txt, then "test" when the
# test tools are installed too: ./run-tests sets setup_extras=test before sourcing this,
# ./run-demo needs none (pytest, playwright and the rest: ~10 s of a first install).
stamp=.venv/.pipestitch-installed
want=$(cat pyproject.toml constraints.txt | sha256sum | cut -d' ' -f1)
extras=${setup_extras:-}
have=$(cat "$stamp" 2>/dev/null || true)
if [ "${have%% *}" != "$want" ] || { [ -n "$extras" ] && [ "$have" != "$want $extras" ]; }; then
  echo "installing pipestitch and its dependencies into .venv ..." >&2
  # uv (from PyPI, at the version constraints.txt names; put into .venv by the venv's
  # pip, or by the interpreter's own where the venv has none yet) installs the same
  # versions several times faster than pip, its downloads and unpacking in parallel
  # (docs/benchmarks.md), and pip into .venv with them; where it cannot be installed
  # or fails, pip installs them (uv reads its own settings, e.g. UV_DEFAULT_INDEX for
  # a mirror, not pip's). Either way without bytecode (see below).
  pip_of_venv=(.venv/bin/python -m pip)
  if ! "${pip_of_venv[@]}" --version >/dev/null 2>&1; then
    pip_of_venv=("$PY" -m pip --python .venv/bin/python)
  fi
  if ! { "${pip_of_venv[@]}" install --quiet --disable-pip-version-check \
           -c constraints.txt uv >&2 \
         && .venv/bin/uv pip install --quiet --python .venv/bin/python \
           -c constraints.txt pip -e ".${extras:+[$extras]}" >&2; }; then
    echo "installing with pip instead (uv could not be installed or failed) ..." >&2
    .venv/bin/python -m pip --version >/dev/null 2>&1 || .venv/bin/python -m ensurepip >/dev/null
    .venv/bin/python -m pip install --quiet --upgrade pip >&2
    .venv/bin/python -m pip install --quiet --no-compile -c constraints.txt \
      -e ".${extras:+[$extras]}" >&2
  fi
  # The dependencies' bytecode: for the tests all of it here, by all cores (the suite
  # imports nearly every package, in many processes). For the demo none here: the
  # kernels' compile (below) and the demo write that of the modules they import, as
  # Python does by default, about a third of the files (~950 of ~4,250 outside the
  # packages' tests), so that later commands read it even where
  # PYTHONDONTWRITEBYTECODE is set.
  if [ -n "$extras" ]; then
    .venv/bin/python -c 'import compileall, re, sysconfig as s
for d in {s.get_path("purelib"), s.get_path("platlib")}:
    compileall.compile_dir(d, quiet=2, workers=0, rx=re.compile(r"[/\\]tests?[/\\]"))' \
      >/dev/null 2>&1 || true
  fi
  echo "$want${extras:+ $extras}" > "$stamp"
fi
# The package's bytecode, written here: a run then reads it even where
# PYTHONDONTWRITEBYTECODE is set (as in many containers), instead of compiling every
# module at each start (~0.1 s); up-to-date files are skipped.
.venv/bin/python -m compileall -q src/pipestitch >/dev/null \
  || echo "warning: bytecode not written; each run compiles the modules" >&2
# Compiled here, in parallel processes, the first run loads the kernels instead of
# compiling them (about a minute); a failure only leaves them to compile on first use.
# Where the install left no bytecode (./run-demo), it writes that of the kernel modules
# and what they import (numba, numpy, ...) once, before its processes start, and they
# read it instead of each compiling those modules again.
env -u PYTHONDONTWRITEBYTECODE .venv/bin/python scripts/compile_kernels.py --stamp .venv/.pipestitch-kernels >&2 \
  || echo "warning: kernels not compiled ahead; the first run compiles them" >&2
