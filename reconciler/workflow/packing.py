"""Making an offline bundle on a laptop (`lpam bundle create`): which desired-state
repository, and a temporary root of its own, so that no lpam installation is needed."""

from __future__ import annotations

import tempfile
from pathlib import Path

from reconciler.base.errors import LpamError
from reconciler.base.layout import Layout
from reconciler.core.documents import load_agent
from reconciler.workflow.bundle import create
from reconciler.workflow.events import Report
from reconciler.workflow.machine import Machine


def make_bundle(layout: Layout, out: Path, *, url: str | None, branch: str | None,
                network_timeout: float, report: Report) -> int:
    """Write the bundle of `url`'s `branch` (default: agent.yaml's under `layout`, else
    the branch main) to `out`; how many repositories it holds."""
    if (url is None or branch is None) and layout.agent_config.exists():
        config = load_agent(layout.agent_config)
        url, branch = url or config.source.url, branch or config.source.branch
    if url is None:
        raise LpamError("which desired-state repository?",
                        hint="pass --source URL (or run where agent.yaml names it)")
    with tempfile.TemporaryDirectory(prefix="lpam-bundle-root-") as tmp:
        machine = Machine.at(Layout(Path(tmp)), network_timeout=network_timeout)
        return create(machine, url, branch or "main", out, report=report)
