"""Implementations of the `Services` port (reconciler/engine/execution/ports.py), one module per
service manager: systemd, supervisord (supervisor.py; its configuration format in
supervisor_conf.py) and the in-memory twin of fast tests (memory.py).
tests/contract/test_services.py holds them to one behaviour."""
