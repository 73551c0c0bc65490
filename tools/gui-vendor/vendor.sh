#!/usr/bin/env bash
# Reproduce the GUI's vendored three.js from the pinned npm package (package-lock.json):
#   bash tools/gui-vendor/vendor.sh
# copies three.js's ES modules and OrbitControls into src/stillcap/gui/static/vendor/three/.
set -euo pipefail
cd "$(dirname "$0")"
npm ci --no-audit --no-fund --silent
out=../../src/stillcap/gui/static/vendor/three
rm -rf "$out" && mkdir -p "$out/addons/controls"
cp node_modules/three/build/three.module.min.js node_modules/three/build/three.core.min.js node_modules/three/LICENSE "$out/"
cp node_modules/three/examples/jsm/controls/OrbitControls.js "$out/addons/controls/"
echo "three $(node -p "JSON.parse(require('fs').readFileSync('node_modules/three/package.json')).version") -> $out"
