#!/usr/bin/env bash
set -euo pipefail
rm -f "$LPAM_ROOT/run/lpam-demo/$LPAM_APP.running"
echo "stopped $LPAM_APP"
