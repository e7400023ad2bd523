# Sourced by the external suites: starts `cloudscape serve` on a free loopback port,
# waits until it is ready, and stops it when the sourcing script exits; and the
# prerequisites the suites share (Python modules, Chromium, npm packages).
#
#   source tests/ext/lib/server.sh
#   need_python jsonschema             # sets $PY, or fails naming what is missing
#   start_server target/some-dir       # log in target/some-dir/server.log
#   echo "$base"                       # http://127.0.0.1:PORT
#   check_server                       # fails if the server died or panicked
#
# Needs the release binary (cargo build --release --bins; CLOUDSCAPE_BIN names another
# one, for example a build of an older commit to see a check fail there) and python3
# (for a free port and the readiness check, without curl). The caller's CLOUDSCAPE_*
# variables reach the server (a request timeout of its own replaces the default below).

bin=${CLOUDSCAPE_BIN:-target/release/cloudscape}
server_pid=""
server_log=""
PY=python3
# ./scripts/test puts numpy, schemathesis and jsonschema in this environment.
if [ -x target/test-venv/bin/python ]; then
  PY=target/test-venv/bin/python
  PATH="$PWD/target/test-venv/bin:$PATH"
fi

stop_server() {
  if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
  server_pid=""
}

# free_port: prints a free loopback TCP port.
free_port() {
  "$PY" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# need_binary: fails with a message unless the release binary is built.
need_binary() {
  if [ ! -x "$bin" ]; then
    echo "error: $bin is missing; run 'cargo build --release --bins' first" >&2
    exit 1
  fi
}

# start_server OUT_DIR [extra args to `cloudscape serve`...]: sets $base.
start_server() {
  local out=$1
  shift
  need_binary
  mkdir -p "$out"
  local port
  port=$(free_port)
  server_log="$out/server.log"
  trap stop_server EXIT
  # A cold tile may take a while on a loaded CI machine: give computations time rather
  # than shedding them.
  RUST_LOG=${RUST_LOG:-warn} \
    CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS=${CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS:-300000} CLOUDSCAPE_SERVER_DRAIN_MS=0 \
    "$bin" serve --listen "127.0.0.1:$port" "$@" >"$server_log" 2>&1 &
  server_pid=$!
  base="http://127.0.0.1:$port"
  for _ in $(seq 1 600); do
    if "$PY" -c "import urllib.request; urllib.request.urlopen('$base/readyz', timeout=2)" 2>/dev/null; then
      return 0
    fi
    if ! kill -0 "$server_pid" 2>/dev/null; then
      echo "error: the server exited; see $server_log" >&2
      cat "$server_log" >&2
      exit 1
    fi
    sleep 0.1
  done
  echo "error: the server did not answer /readyz; see $server_log" >&2
  cat "$server_log" >&2
  exit 1
}

# check_server: fails (showing the log) when the server died or logged a panic.
check_server() {
  if [ -n "$server_pid" ] && ! kill -0 "$server_pid" 2>/dev/null; then
    echo "error: the server died during the run; see $server_log" >&2
    cat "$server_log" >&2
    exit 1
  fi
  if [ -n "$server_log" ] && grep -q "panicked" "$server_log"; then
    echo "error: the server panicked; see $server_log" >&2
    cat "$server_log" >&2
    exit 1
  fi
}

# need_python MODULE...: fails with a message unless $PY imports every MODULE.
need_python() {
  local m
  for m in "$@"; do
    if ! "$PY" -c "import $m" 2>/dev/null; then
      echo "error: the Python package $m is not installed (./scripts/test puts it in target/test-venv)" >&2
      exit 1
    fi
  done
}

# need_chromium: sets $chromium (CHROMIUM, default Debian's) and installs
# tests/browser's npm packages (playwright-core) that drive it.
need_chromium() {
  chromium=${CHROMIUM:-/usr/bin/chromium}
  if [ ! -x "$chromium" ]; then
    echo "error: $chromium is missing; install the Debian package 'chromium'" >&2
    exit 1
  fi
  npm_ci tests/browser
}

# npm_ci DIR: installs DIR's locked npm packages unless they are there already.
npm_ci() {
  local dir=$1
  if [ -d "$dir/node_modules" ] && [ "$dir/node_modules/.package-lock.json" -nt "$dir/package-lock.json" ]; then
    return 0
  fi
  if ! command -v npm >/dev/null 2>&1; then
    echo "error: npm is missing; install the Debian package 'npm'" >&2
    exit 1
  fi
  (cd "$dir" && npm ci --no-audit --no-fund >/dev/null)
}
