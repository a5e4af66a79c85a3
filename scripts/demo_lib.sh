#!/usr/bin/env bash
# Shared by demo.sh and demo_rig.sh (sourced): DEMO_TAG names the demo in messages.

# wait_for_line FILE PATTERN SECONDS: wait until a process has logged PATTERN.
wait_for_line() {
  local deadline=$((SECONDS + $3))
  until grep -q "$2" "$1" 2>/dev/null; do
    if ((SECONDS > deadline)); then
      echo "[$DEMO_TAG] timed out waiting for '$2' in $1:" >&2
      cat "$1" >&2
      exit 1
    fi
    sleep 0.1
  done
}
