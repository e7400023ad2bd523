# Sourced by the external suites: starts `cloudscape serve` on a free loopback port,
# waits for /healthz, and stops it when the sourcing script exits.
#
#   source tests/ext/lib/server.sh
#   start_server target/some-dir       # log in target/some-dir/server.log
#   echo "$base"                       # http://127.0.0.1:PORT
#
# Needs the release binary (cargo build --release --bins) and node (for a free port
# and the health check, without curl).

bin=target/release/cloudscape
server_pid=""
server_log=""

stop_server() {
  if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
  server_pid=""
}

# start_server OUT_DIR [extra args to `cloudscape serve`...]: sets $base.
start_server() {
  local out=$1
  shift
  if [ ! -x "$bin" ]; then
    echo "error: $bin is missing; run 'cargo build --release --bins' first" >&2
    exit 1
  fi
  mkdir -p "$out"
  local port
  port=$(node -e 'const s=require("net").createServer().listen(0,"127.0.0.1",()=>{console.log(s.address().port);s.close()})')
  server_log="$out/server.log"
  trap stop_server EXIT
  # A cold tile may take a while on a loaded CI machine: give computations time rather
  # than shedding them.
  CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS=300000 CLOUDSCAPE_SERVER_DRAIN_MS=0 \
    "$bin" serve --listen "127.0.0.1:$port" "$@" >"$out/server.log" 2>&1 &
  server_pid=$!
  base="http://127.0.0.1:$port"
  for _ in $(seq 1 200); do
    if node -e "fetch('$base/healthz').then(r=>process.exit(r.ok?0:1),()=>process.exit(1))"; then
      return 0
    fi
    if ! kill -0 "$server_pid" 2>/dev/null; then
      echo "error: the server exited; see $out/server.log" >&2
      cat "$out/server.log" >&2
      exit 1
    fi
    sleep 0.1
  done
  echo "error: the server did not answer /healthz; see $out/server.log" >&2
  exit 1
}

# check_no_panic: fails (showing the log) when the server logged a panic.
check_no_panic() {
  if [ -n "$server_log" ] && grep -q "panicked" "$server_log"; then
    echo "error: the server panicked; see $server_log" >&2
    cat "$server_log" >&2
    exit 1
  fi
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
