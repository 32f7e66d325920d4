#!/usr/bin/env bash
# Start: a real app would start its service here; the demo leaves a marker that it runs.
set -euo pipefail
mkdir -p "$LPAM_ROOT/run/lpam-demo"
env | grep -E '^(LPAM_|LOG_|SPEED_)' | sort > "$LPAM_ROOT/run/lpam-demo/$LPAM_APP.running"
echo "started $LPAM_APP"
