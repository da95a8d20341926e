#!/usr/bin/env bash
# tests/integ/demo_key.sh - `make demo` makes its API key fresh each run
# (tests/demo.sh --key prints one as a run makes it): two runs differ, and
# each is a key farm.ini takes (16..128 of letters, digits, '-', '_').
set -u
cd "$(dirname "$0")/../.."
a=$(tests/demo.sh --key) || { echo "FAIL: tests/demo.sh --key"; exit 1; }
b=$(tests/demo.sh --key)
[ "$a" != "$b" ] || { echo "FAIL: two demo runs made the same key '$a'"; exit 1; }
for k in "$a" "$b"; do
  [[ "$k" =~ ^[A-Za-z0-9_-]{16,128}$ ]] || { echo "FAIL: demo key '$k' is not a valid API key"; exit 1; }
done
grep -q 'key=demo-key' tests/demo.sh && { echo "FAIL: tests/demo.sh still has a fixed key"; exit 1; }
echo "ok: demo keys differ"
