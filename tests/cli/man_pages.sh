#!/usr/bin/env bash
# The man pages (docs/man) against the programs: every configuration key
# gazesplatd --check-config prints is in gazesplatd.conf(5), every command
# `gazesplat --help` lists is in gazesplat(1), every flag `gazesplatd
# --help` lists is in gazesplatd(8), and each page formats without
# warnings when man(1) is there.
set -euo pipefail
G=$1 D=$2 MAN=$3
fail() { echo "FAIL: $*"; exit 1; }
# roff writes '-' as '\-': compare on the text with that undone.
# The tag lines of .TP entries: where a key or a command is described.
tags() { awk 'tp { print; tp = 0 } /^\.TP/ { tp = 1 }' "$MAN/$1" | sed 's/\\-/-/g'; }
conf=$(tags gazesplatd.conf.5)
cli=$(tags gazesplat.1)
daemon=$(sed 's/\\-/-/g' "$MAN/gazesplatd.8")
keys=$("$D" --check-config | sed -n 's/^\([a-z_.]*\) =.*/\1/p')
[ -n "$keys" ] || fail "no keys from --check-config"
for key in $keys; do
  grep -E "^\.BR? .*\b$key\b" <<<"$conf" >/dev/null || fail "gazesplatd.conf.5 lacks key $key"
done
cmds=$("$G" --help | sed -n 's/^  \([a-z-]*\) .*/\1/p')
[ -n "$cmds" ] || fail "no commands from gazesplat --help"
for cmd in $cmds; do
  grep -E "^\.BR? .*\b$cmd\b" <<<"$cli" >/dev/null || fail "gazesplat.1 lacks command $cmd"
done
for flag in $("$D" --help | grep -o -- '--[a-z-]*' | sort -u); do
  grep -F -- "$flag" <<<"$daemon" >/dev/null || fail "gazesplatd.8 lacks $flag"
done
if command -v man >/dev/null 2>&1; then
  for p in gazesplat.1 gazesplatd.8 gazesplatd.conf.5; do
    out=$(LC_ALL=C.UTF-8 MANWIDTH=80 man --warnings -l "$MAN/$p" 2>&1 >/dev/null) || true
    [ -z "$out" ] || fail "$p: $out"
  done
fi
echo "man_pages: ok"
