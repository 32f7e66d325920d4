"""Where an update gate gets the vehicle's CAN frames from (python-can underneath).

`sources.open_source` opens one of three kinds of source — a live bus, the recording app's
libpanda CSV followed as it grows, a log file — behind one `FrameSource` protocol; the gate
decodes the speed from what they yield. Nothing here is imported until a gate is checked:
python-can alone costs about 0.1 s to import.
"""
