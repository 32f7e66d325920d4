"""Use cases written once for every caller (the CLI today; the agent and the Bluetooth
service later): each takes its ports and a progress callback, and returns what happened."""
