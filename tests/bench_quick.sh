#!/bin/sh
# One benchmark's --quick smoke run (make test-bench runs them JOBS at a time): its output goes to
# build/bench-quick/NAME.log, printed in part when it fails.
name=$(basename "$2" .py)
mkdir -p build/bench-quick
start=$(date +%s)
if "$1" "$2" --quick > "build/bench-quick/$name.log" 2>&1; then
  echo "$2 --quick: ok in $(( $(date +%s) - start )) s"
else
  echo "$2 --quick FAILED after $(( $(date +%s) - start )) s:"; tail -40 "build/bench-quick/$name.log"; exit 1
fi
