#!/usr/bin/env bash
# The container image builds: its build stage compiles from exactly what
# docker/Dockerfile COPYs. No container engine runs on the CI machine (no daemon; see
# README "Scaling out"), so this does what the build stage does without one: it
# copies the paths of every COPY of the build stage out of the repository, filtered by
# .dockerignore as Docker filters the build context (the last matching pattern wins,
# `!` re-includes, `*` does not cross `/`, `**` does, a directory pattern takes what is
# under it), into an empty directory, and runs `cargo check --locked --offline --bin
# cloudscape` there (the Dockerfile's `cargo build --release --locked --bin
# cloudscape`, without code generation). A file the build reads but the Dockerfile
# does not copy (an include_str! of a file left out) fails it. Then it checks that the
# Dockerfile's runtime stage copies the binary the build stage produced.
#
# It builds into the repository's target/ (the dependencies' artifacts are shared; the
# copied crates, at another path, get artifacts of their own), so after the suite's
# clippy run it compiles only the workspace's crates. Needs python3 and cargo;
# installs nothing.
set -euo pipefail
cd "$(dirname "$0")/../.."

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

python3 - "$work/context" <<'EOF'
import os, re, shutil, sys

dest = sys.argv[1]
lines = open("docker/Dockerfile").read().replace("\\\n", " ").splitlines()

# The COPY sources of the first (build) stage, not those copied from another stage.
stage, sources = 0, []
for line in lines:
    words = line.split()
    if not words or words[0].startswith("#"):
        continue
    if words[0].upper() == "FROM":
        stage += 1
    elif words[0].upper() == "COPY" and stage == 1:
        args = [w for w in words[1:] if not w.startswith("--")]
        if any(w.startswith("--from") for w in words[1:]):
            continue
        sources += args[:-1]
if not sources:
    sys.exit("error: no COPY in the build stage of docker/Dockerfile")

def pattern_regex(p):
    """A .dockerignore pattern as a regex over /-separated paths (Go filepath.Match
    plus `**`)."""
    out, i = "", 0
    while i < len(p):
        if p.startswith("**", i):
            out += ".*"
            i += 2
        elif p[i] == "*":
            out += "[^/]*"
            i += 1
        elif p[i] == "?":
            out += "[^/]"
            i += 1
        else:
            out += re.escape(p[i])
            i += 1
    # A pattern that names a directory also takes everything under it.
    return re.compile("^" + out + "(/.*)?$")

rules = []
for raw in open(".dockerignore").read().splitlines():
    raw = raw.strip()
    if not raw or raw.startswith("#"):
        continue
    negate = raw.startswith("!")
    pat = os.path.normpath(raw.lstrip("!").strip("/"))
    rules.append((negate, pattern_regex(pat)))

def ignored(path):
    result = False
    for negate, rx in rules:
        if rx.match(path):
            result = not negate
    return result

copied = 0
for src in sources:
    src = os.path.normpath(src)
    if not os.path.exists(src):
        sys.exit(f"error: docker/Dockerfile copies {src}, which does not exist")
    paths = [src] if os.path.isfile(src) else [
        os.path.normpath(os.path.join(root, f)) for root, _, files in os.walk(src) for f in files
    ]
    for p in paths:
        if ignored(p):
            continue
        os.makedirs(os.path.join(dest, os.path.dirname(p)), exist_ok=True)
        shutil.copy2(p, os.path.join(dest, p))
        copied += 1
    if copied == 0:
        sys.exit(f"error: .dockerignore leaves nothing of {src}")
print(f"copied {copied} files from the COPY sources {' '.join(sources)}")
EOF

status=0
echo "== cargo check --locked --offline --bin cloudscape (in the build context)"
target="$PWD/target"
if (cd "$work/context" && CARGO_TARGET_DIR="$target" cargo check --locked --offline --bin cloudscape --quiet); then
  echo "ok - the build stage compiles from exactly what the Dockerfile copies"
else
  echo "FAILED: the build stage does not compile from what docker/Dockerfile copies"
  status=1
fi

# The runtime stage takes the binary the build stage installed.
built=$(grep -E '^\s*&& cp target/release/cloudscape ' docker/Dockerfile | awk '{print $NF}')
taken=$(grep -E '^COPY --from=build ' docker/Dockerfile | awk '{print $3}')
if [ -n "$built" ] && [ "$built" = "$taken" ]; then
  echo "ok - the runtime stage copies $built from the build stage"
else
  echo "FAILED: the build stage installs '$built' but the runtime stage copies '$taken'"
  status=1
fi
exit $status
