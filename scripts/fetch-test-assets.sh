#!/usr/bin/env bash
# Fetches the real-face test photos: demo/sample1..6.jpg of the npm package
# @vladmandic/face-api 1.7.15 (MIT, the author's own photos), into
# DIR/face-api/ (default DIR: assets/ at the repository root, git-ignored).
# npm checks the tarball against the registry's integrity hash; the photos
# are then checked against the SHA-256 sums below. Idempotent: nothing is
# fetched when the photos are already there and intact.
set -euo pipefail
cd "$(dirname "$0")/.."
dir="${1:-assets}/face-api"
pkg="@vladmandic/face-api@1.7.15"

sums() {
  cat <<'SUMS'
8ecae4b267b2d3169e06e00c7dee97097aa2a94635d45216f7732a5f4943cb51  sample1.jpg
7d2b60ae6f13bf30f422e04df87451081a02c83de469056f25afb44b7000c691  sample2.jpg
8eb081c9efb14370fa94d9feab9e5fbeafd19a627491853a80c2bf67f7ffa936  sample3.jpg
729efa5923061d40eb4ed5f267a18cc7b8ba6f852bb2757b16d8b7e4937476fc  sample4.jpg
6d45095ebb182d8f975c0790e0e4eefd86fbb40609cf4b271776d92e12662938  sample5.jpg
9baad80f9d5e306fb9b8c0913d44445f1e95848df317530efb03d0934c57ba87  sample6.jpg
SUMS
}

if [ -d "$dir" ] && (cd "$dir" && sums | sha256sum --check --quiet --status); then
  echo "fetch-test-assets: $dir up to date"
  exit 0
fi
mkdir -p "$dir"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && npm pack --silent "$pkg" >/dev/null)
tar -xzf "$tmp"/vladmandic-face-api-1.7.15.tgz -C "$tmp" \
  package/demo/sample1.jpg package/demo/sample2.jpg package/demo/sample3.jpg \
  package/demo/sample4.jpg package/demo/sample5.jpg package/demo/sample6.jpg \
  package/LICENSE
cp "$tmp"/package/demo/sample*.jpg "$tmp"/package/LICENSE "$dir"/
(cd "$dir" && sums | sha256sum --check --quiet)
echo "fetch-test-assets: $pkg demo photos in $dir"
