"""A scriptless example app: lpam runs it as a service (no install/start/stop scripts).

It prints a (made-up) vehicle speed twice a second. With CRASH_AFTER=N it exits with an
error after N seconds, as a broken release would: the demo uses that to show a health
check failing and lpam rolling back to the version that worked.
"""

import math
import os
import sys
import time

from speedunits import to_unit  # a pip dependency: lpam-demo-speedunits

rate = float(os.environ.get("RATE_HZ", "2"))
crash_after = os.environ.get("CRASH_AFTER")
started = time.monotonic()
print(f"speed-logger {os.environ.get('LPAM_APP', '?')} starting at {rate:g} Hz", flush=True)
while True:
    elapsed = time.monotonic() - started
    if crash_after is not None and elapsed >= float(crash_after):
        print("speed-logger: lost the CAN bus, giving up", flush=True)
        sys.exit(1)
    unit = os.environ.get("SPEED_UNIT", "km/h")
    print(f"speed {to_unit(50 + 20 * math.sin(elapsed / 5), unit):.1f} {unit}", flush=True)
    time.sleep(1 / rate)
