"""The front ends: the CLI, libpanda-app-manager and the phone's Bluetooth service.

Each parses what its caller says, calls one use case of reconciler/workflow and renders
what it returns; no rule lives here."""
