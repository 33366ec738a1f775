#!/usr/bin/env bash
# The Node packages the glTF tests (tests/node: glTF-Validator, three.js) and the web page's
# browser tests (web/: playwright-core, driving the system chromium) use, exactly as pinned in
# their package-lock.json files. Run by `make test`; skipped when the lock has not changed
# since the last install.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v npm >/dev/null; then
  echo "npm not found: the glTF and web tests need Node.js (apt-get install nodejs npm)" >&2
  exit 0  # the tests that need it fail and say so
fi
for dir in tests/node web; do
  stamp="$dir/node_modules/.lock-$(cksum < "$dir/package-lock.json" | cut -d' ' -f1)"
  [ -e "$stamp" ] && continue
  (cd "$dir" && npm ci --no-audit --no-fund)
  touch "$stamp"
done
