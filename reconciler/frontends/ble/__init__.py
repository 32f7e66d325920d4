"""`lpam ble`: the Bluetooth service the field's phone app (Privzone) talks to.

Three parts, each replaceable on its own: the protocol (reconciler/core/privzone/, pure), the
D-Bus GATT server registered with BlueZ (reconciler/adapters/bluez/), and this package,
which answers the phone through lpam's own workflow functions (`answers.py`), one at a
time and off the GATT loop (`bridge.py`), and runs the whole (`serve.py`).
"""
