"""What lpam knows of the vehicle itself, for the update gates that run before a cutover.

An app may only be swapped while the car is parked; the speed comes from the CAN bus. This
package holds the pure part of that question — how one signal is read out of a frame — so
that it can be tested against recordings and against cantools without a bus; opening a bus
or following a recording belongs to the adapters.
"""
