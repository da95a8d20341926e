#!/usr/bin/env bash
# tests/check-size.sh - one job per file: no production source file (src,
# slicer, drivers, sim) over 1000 lines and no function over 120 lines.
# A function runs from its opening "{" at column 0 to its closing "}" at
# column 0 (clang-format's Linux braces put every definition's braces
# there).  Prints every offender; with --report, the longest files and
# functions instead, and never fails.
set -u
max_file=1000 max_fn=120
files=$(git ls-files 'src/*' 'slicer/*' 'drivers/*' 'sim/*' | grep -E '\.(c|h|cpp)$')
fns=$(awk '
  /^\{$/ { start = FNR; name = prev; next }
  /^\}/ && start { print FNR - start + 1, FILENAME ":" start, name; start = 0 }
  { if ($0 ~ /^[A-Za-z_].*\(/) { prev = $0; sub(/\(.*/, "", prev); sub(/.*[ *]/, "", prev) } }
' $(grep -E '\.(c|cpp)$' <<< "$files") | sort -rn)
lens=$(wc -l $files | grep -v ' total$' | sort -rn)
if [ "${1:-}" = --report ]; then
  echo "files over $max_file lines: $(awk -v m=$max_file '$1 > m' <<< "$lens" | wc -l)"
  head -5 <<< "$lens"
  echo "functions over $max_fn lines: $(awk -v m=$max_fn '$1 > m' <<< "$fns" | wc -l)" \
    "(over 100: $(awk '$1 > 100' <<< "$fns" | wc -l))"
  head -5 <<< "$fns"
  exit 0
fi
bad=$( (awk -v m=$max_file '$1 > m { print $2 ": " $1 " lines (most " m ")" }' <<< "$lens"
        awk -v m=$max_fn '$1 > m { print $2 ": function " $3 " is " $1 " lines (most " m ")" }' <<< "$fns"))
[ -z "$bad" ] && { echo "size: every file under $max_file lines, every function under $max_fn"; exit 0; }
echo "$bad"
echo "split at the code's seams (see README, Code map): one job per file"
exit 1
