"""A saved plan is refused when it is loaded — before the apply lock is taken — when a
step is of an unknown kind, lacks a field, has a field of the wrong type, or was edited
after the plan was sealed; each fault at its file:line:column."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pytest

from reconciler.base.errors import ConfigError
from reconciler.base.layout import Layout
from reconciler.core.documents import load_plan
from reconciler.core.planning.lifecycle import generation_of, on
from reconciler.core.planning.model import AppTarget, HealthTarget
from reconciler.core.planning.plan import seal as sealed
from reconciler.engine.execution.lock import apply_lock
from reconciler.frontends import cli
from schemas.plan import CheckoutStep, HealthCheck, Phase, StepKind, VerifyStep
from schemas.record import StateRecord

C, T = "a" * 40, "b" * 40
APP = AppTarget(name="x", repository="lab/apps", commit=C, path="x", tree=T,
                health=HealthTarget(settle_seconds=2, can_ids=(0x1A,)))


def saved(tmp_path: Path, edit: Callable[[dict[str, Any]], object] | None = None) -> Path:
    """A sealed plan (checkout, install, verify) as `lpam plan -o` writes it; `edit`
    changes its JSON afterwards."""
    gen = generation_of(APP, APP.generation or "")
    steps = [
        CheckoutStep(id="checkout:lab/apps", phase=Phase.PREPARE, key="lab/apps",
                     url="git://h/apps.git", ref="main", commit=C),
        on(StepKind.INSTALL, "x", gen),
        VerifyStep(id="verify:x", phase=Phase.CUTOVER, app=gen,
                   health=HealthCheck(settle_seconds=2, timeout_seconds=10, can_ids=[0x1A])),
    ]
    plan = sealed(StateRecord(lineage="l-1", serial=3), [], steps,
                  now=datetime(2026, 11, 24, tzinfo=timezone.utc), lpam_version="t",
                  summary="")
    data = json.loads(plan.model_dump_json())
    if edit is not None:
        edit(data)
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(data, indent=2) + "\n")
    return path


def line_of(path: Path, text: str) -> int:
    """The first line holding `text` (1-based); `"a" {`: the first `{` after `"a"`."""
    lines = path.read_text().splitlines()
    first, _, then = text.partition(" ")
    at = next(n for n, line in enumerate(lines, 1) if first in line)
    return at if not then else next(n for n, line in enumerate(lines, 1)
                                    if n > at and then in line)


def test_a_sealed_plan_loads(tmp_path: Path) -> None:
    plan = load_plan(saved(tmp_path))
    assert [s.kind for s in plan.steps] == [StepKind.CHECKOUT, StepKind.INSTALL,
                                            StepKind.VERIFY]
    verify = plan.steps[2]
    assert isinstance(verify, VerifyStep) and verify.health.can_ids == [0x1A]


def _step(index: int, **changes: Any) -> Callable[[dict[str, Any]], object]:
    return lambda data: data["steps"][index].update(changes)


def _drop(index: int, *path: str) -> Callable[[dict[str, Any]], object]:
    def edit(data: dict[str, Any]) -> None:
        node = data["steps"][index]
        for part in path[:-1]:
            node = node[part]
        del node[path[-1]]
    return edit


def _stop_of_both(index: int) -> Callable[[dict[str, Any]], object]:
    def edit(data: dict[str, Any]) -> None:
        step = data["steps"][index]
        del step["good"]
        step.update(kind="stop", stray={"name": "x", "generation": "g"})
    return edit


EDITS: dict[str, tuple[Callable[[dict[str, Any]], object], str, str]] = {
    # name: (edit, what the error says, the text on the line it points at)
    "edited step arg": (_step(0, commit="f" * 40), "fingerprint does not match",
                        '"fingerprint"'),
    "edited health": (lambda d: d["steps"][2]["health"].update(settle_seconds=0),
                      "fingerprint does not match", '"fingerprint"'),
    "edited fingerprint": (lambda d: d.update(fingerprint="0" * 64),
                           "fingerprint does not match", '"fingerprint"'),
    "unknown kind": (_step(1, kind="reboot"), "steps.1.kind: unknown kind 'reboot'",
                     '"reboot"'),
    "missing field": (_drop(1, "app", "repository"), "steps.1.app.repository: Field required",
                      '"app"'),
    "bad type": (lambda d: d["steps"][2]["health"].update(settle_seconds="soon"),
                 "steps.2.health.settle_seconds", '"soon"'),
    # at the step's `{`: the first after the checkout's url
    "stray and app": (_stop_of_both(1), "give either `app` or `stray`", '"url" {'),
}


@pytest.mark.parametrize("name", sorted(EDITS))
def test_a_tampered_plan_is_refused_at_load_with_its_location(tmp_path: Path,
                                                              name: str) -> None:
    edit, said, at = EDITS[name]
    path = saved(tmp_path, edit)
    with pytest.raises(ConfigError) as info:
        load_plan(path)
    assert said in info.value.message
    assert info.value.path == path and info.value.hint
    assert info.value.line == line_of(path, at) and info.value.column is not None


@pytest.mark.parametrize("name", sorted(EDITS))
def test_lpam_apply_refuses_a_tampered_plan_before_the_lock(
    tmp_path: Path, name: str, capsys: pytest.CaptureFixture[str],
) -> None:
    root = tmp_path / "root"
    path = saved(tmp_path, EDITS[name][0])
    assert cli.main(["--root", str(root), "apply", str(path)]) != 0
    assert EDITS[name][1] in capsys.readouterr().err
    assert not Layout(root).lock.exists()  # never opened, so never taken


def test_a_tampered_plan_is_refused_at_once_while_another_apply_holds_the_lock(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    root = tmp_path / "root"
    layout = Layout(root)
    path = saved(tmp_path, EDITS["edited step arg"][0])
    with apply_lock(layout, timeout=0):
        began = time.monotonic()
        code = cli.main(["--root", str(root), "apply", "--lock-timeout", "30", str(path)])
        took = time.monotonic() - began
    err = capsys.readouterr().err
    assert code != 0 and took < 10
    assert "fingerprint does not match" in err and f"{path}:" in err
