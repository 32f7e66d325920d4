"""The fleet page (`lpam fleet report`): one self-contained HTML document, drawn from a
`FleetView` alone (report/fleetview.py).

Why it is made the way it is:

- one file, inline CSS and SVG, no script, no font or image to fetch: it opens from a
  laptop's disk, from a git host's pages, or from a phone that has no network in the
  garage, and shows the same thing everywhere;
- every state is a word and a symbol (✓ confirmed, … waiting, ↺ rolled back, ? unknown: glyphs every
  system font has);
  colour only repeats it, so a colour-blind reader or a screen reader loses nothing; each
  timeline is an `<svg role="img">` whose `<title>` names the car, and each mark carries
  its own `<title>` (what ran, when; why it rolled back);
- on a phone the tables scroll sideways in their own box and the timelines scale to the
  width (viewBox);
- every text comes from the cars (ids, reasons, app names): all of it is escaped;
- built as one list of strings joined once; a timeline draws at most `MARKS` marks, and of
  the instants (deferrals) one per kind on a pixel of the 1000-unit axis, but every
  rollback: a hundred cars' thirty days stay a page drawn in milliseconds
  (bench/fleetpage.py).
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime
from html import escape

from reconciler.report.fleetview import (
    CarView,
    FleetView,
    Mark,
    RevisionSummary,
    State,
    ago,
)

WIDTH = 1000.0
"""The timelines' axis in SVG units (the page scales it to the screen)."""

MARKS = 400
"""The most marks one car's timeline draws (rollbacks always among them)."""

SYMBOL: dict[State, str] = {"confirmed": "✓", "waiting": "…", "rolled back": "↺",
                            "unknown": "?"}

STYLE = """
body{font:15px/1.4 system-ui,sans-serif;margin:0 auto;max-width:1200px;padding:12px;color:#111}
h1{font-size:1.3em}h2{font-size:1.1em;margin-top:1.6em}
.scroll{overflow-x:auto}table{border-collapse:collapse;min-width:100%}
th,td{border-bottom:1px solid #ddd;padding:4px 8px;text-align:left;vertical-align:top}
.state,th[scope=row]{font-weight:600;white-space:nowrap}
.state-confirmed{color:#0a6b2d}.state-waiting{color:#8a5a00}
.state-rolled-back{color:#b00020}.state-unknown{color:#555}
.car{margin:10px 0}.car h3{font-size:1em;margin:0}
svg{width:100%;height:auto;display:block}
.ran{fill:#4a7fb5}.ran.uncertain{fill:#9bb7d4}.rollback{fill:#b00020}
.deferral{fill:#c68a00}.wait{fill:#c68a00}.unknown{fill:#777}
.legend span{margin-right:1.2em;white-space:nowrap}
"""


def render(view: FleetView) -> str:
    """The page, as text (UTF-8 when written)."""
    out: list[str] = [
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">",
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">",
        "<title>Fleet report</title><style>", STYLE, "</style></head><body>",
        "<h1>Fleet report</h1>",
        f"<p>The cars follow <code>{_short(view.tip)}</code>. Built "
        f"{escape(_time(view.generated))} from the cars' published statuses; timelines from "
        f"{escape(_time(view.since))}.</p>",
    ]
    if view.rollout:
        out.append(f"<p id=\"rollout\">Rollout: {escape(view.rollout)}</p>")
    out += _summary(view.revisions)
    out += _cars(view)
    out.append("<h2>Timelines</h2>")
    out.append("<p class=\"legend\"><span>▬ ran (lighter: its end uncertain)</span> "
               "<span>▲ rolled back or failed</span> <span>◆ deferred (a gate, a wave)"
               "</span> <span>● unknown</span></p>")
    for car in view.cars:
        out += _timeline(car, view.since, view.generated)
    out.append("</body></html>\n")
    return "".join(out)


def _summary(revisions: tuple[RevisionSummary, ...]) -> list[str]:
    out = ["<h2>By desired revision</h2><div class=\"scroll\"><table id=\"revisions\">",
           "<tr><th scope=\"col\">Revision</th><th scope=\"col\">✓ confirmed</th>"
           "<th scope=\"col\">… waiting</th><th scope=\"col\">↺ rolled back</th>"
           "<th scope=\"col\">? unknown</th></tr>"]
    for r in revisions:
        out.append(f"<tr><th scope=\"row\"><code>{_short(r.revision)}</code></th>"
                   f"<td>{r.confirmed}</td><td>{r.waiting}</td><td>{r.failed}</td>"
                   f"<td>{r.unknown}</td></tr>")
    out.append("</table></div>")
    return out


def _cars(view: FleetView) -> list[str]:
    out = ["<h2>Cars</h2><div class=\"scroll\"><table id=\"cars\"><tr>",
           *(f"<th scope=\"col\">{h}</th>" for h in (
               "Vehicle", "State", "Why", "Revision", "Apps", "Waits for", "Override",
               "Last report")),
           "</tr>"]
    for car in view.cars:
        slug = car.state.replace(" ", "-")
        out.append(
            f"<tr id=\"car-{escape(car.vehicle)}\" data-state=\"{escape(car.state)}\">"
            f"<th scope=\"row\">{escape(car.vehicle)}</th>"
            f"<td class=\"state state-{slug}\">{SYMBOL[car.state]} {escape(car.state)}</td>"
            f"<td>{escape(car.detail)}</td><td><code>{_short(car.revision)}</code></td>"
            f"<td>{escape(', '.join(car.apps)) or '-'}</td>"
            f"<td>{escape(car.gate or '-')}</td><td>{escape(car.override or '-')}</td>"
            f"<td>{escape(_age(car.reported, view.generated))}</td></tr>")
    out.append("</table></div>")
    return out


def _timeline(car: CarView, since: datetime, until: datetime) -> list[str]:
    span = max((until - since).total_seconds(), 1.0)

    def x(moment: datetime) -> float:
        return min(max((moment - since).total_seconds() / span * WIDTH, 0.0), WIDTH)

    name = escape(car.vehicle)
    out = [f"<div class=\"car\"><h3>{name}: {SYMBOL[car.state]} {escape(car.state)}</h3>",
           f"<svg data-vehicle=\"{name}\" role=\"img\" aria-label=\"timeline of {name}\" "
           f"viewBox=\"0 0 {WIDTH:g} 40\" preserveAspectRatio=\"none\">"
           f"<title>What ran on {name}, {escape(_time(since))} to "
           f"{escape(_time(until))}</title>",
           "<line x1=\"0\" y1=\"20\" x2=\"1000\" y2=\"20\" stroke=\"#ccc\"/>"]
    for mark in _thinned(car.marks, x):
        begin = x(mark.start)
        title = f"<title>{escape(mark.label)}: {escape(_when(mark))}</title>"
        if mark.kind == "ran":
            end = x(mark.end or until)
            uncertain = " uncertain" if "uncertain" in mark.label else ""
            out.append(f"<rect class=\"ran{uncertain}\" data-kind=\"ran\" x=\"{begin:.1f}\" "
                       f"y=\"12\" width=\"{max(end - begin, 1.0):.1f}\" height=\"16\">"
                       f"{title}</rect>")
        elif mark.kind == "rollback":
            out.append(f"<path class=\"rollback\" data-kind=\"rollback\" d=\"M{begin:.1f} 2 "
                       f"l6 10 h-12 z\">{title}</path>")
        elif mark.kind in ("deferral", "wait"):
            out.append(f"<path class=\"{mark.kind}\" data-kind=\"{mark.kind}\" "
                       f"d=\"M{begin:.1f} 28 l5 5 l-5 5 l-5 -5 z\">{title}</path>")
        else:
            out.append(f"<circle class=\"unknown\" data-kind=\"unknown\" cx=\"{begin:.1f}\" "
                       f"cy=\"34\" r=\"4\">{title}</circle>")
    out.append("</svg></div>")
    return out


def _thinned(marks: tuple[Mark, ...], place: Callable[[datetime], float]) -> list[Mark]:
    """At most MARKS marks: every rollback, then the others newest first, dropping an
    instant that lands on the same pixel as one of its kind kept before it."""
    kept: list[Mark] = [m for m in marks if m.kind == "rollback"]
    seen: set[tuple[str, int]] = set()
    for mark in reversed(marks):
        if mark.kind == "rollback" or len(kept) >= MARKS:
            continue
        key = (mark.kind, int(place(mark.start)))
        if mark.end == mark.start and key in seen:
            continue
        seen.add(key)
        kept.append(mark)
    return sorted(kept, key=lambda m: m.start)


def _short(revision: str | None) -> str:
    return escape(revision[:12]) if revision else "none"


def _time(moment: datetime) -> str:
    return moment.isoformat(timespec="minutes")


def _when(mark: Mark) -> str:
    if mark.end == mark.start:
        return _time(mark.start)
    return f"{_time(mark.start)} to {_time(mark.end) if mark.end else 'now'}"


def _age(reported: datetime | None, now: datetime) -> str:
    return "never" if reported is None else ago((now - reported).total_seconds())
