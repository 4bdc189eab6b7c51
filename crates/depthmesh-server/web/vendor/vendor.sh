#!/usr/bin/env bash
# Rebuilds vendor.min.js, the one file of third-party code the browser view
# loads, from the versions pinned in package.json and package-lock.json.
# Needs npm and the npm registry; the build of depthmesh itself needs neither.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cp "$here/package.json" "$here/entry.js" "$work/"
[ -f "$here/package-lock.json" ] && cp "$here/package-lock.json" "$work/"
cd "$work"
if [ -f package-lock.json ]; then npm ci --no-audit --no-fund; else npm install --no-audit --no-fund; fi
npx esbuild entry.js --bundle --format=esm --minify --legal-comments=eof \
  --outfile="$here/vendor.min.js"
cp package-lock.json "$here/"
version() { node -p "JSON.parse(require('fs').readFileSync('node_modules/$1/package.json')).version"; }
{
  echo "three $(version three) (MIT, LICENSE.three)"
  echo "meshoptimizer $(version meshoptimizer) (MIT, LICENSE.meshoptimizer)"
} > "$here/VERSIONS"
cat node_modules/three/LICENSE > "$here/LICENSE.three"
cat node_modules/meshoptimizer/LICENSE.md > "$here/LICENSE.meshoptimizer"
