#!/usr/bin/env bash
# Install: put the app's files where it runs from. lpam passes LPAM_ROOT, LPAM_APP,
# LPAM_APP_DIR and the app's params as environment variables.
set -euo pipefail
mkdir -p "$LPAM_ROOT/opt/$LPAM_APP"
cp -r "$LPAM_APP_DIR/." "$LPAM_ROOT/opt/$LPAM_APP/"
echo "installed $LPAM_APP from $LPAM_APP_DIR"
