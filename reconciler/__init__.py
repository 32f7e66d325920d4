"""lpam: make a research vehicle's Pi match a declared desired state of its experiment apps."""

__version__ = "0.1.0"
