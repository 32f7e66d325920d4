#!/usr/bin/env bash
set -euo pipefail
rm -rf "${LPAM_ROOT:?}/opt/$LPAM_APP"
echo "uninstalled $LPAM_APP"
