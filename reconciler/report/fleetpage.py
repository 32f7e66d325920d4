"""The fleet page (`lpam fleet report`): a FleetView (report/fleetview.py) drawn as one
self-contained HTML document — inline CSS and inline SVG, no script, no font, no image, no
request — so that it opens the same from a file, from a mail attachment or from a git host's
pages, on a desk or on a phone at 6 am.

What a car says is not trusted: every vehicle id, label, reason and app name goes through
`_text` (control characters replaced, then HTML-escaped), so a car named `<script>` shows
that name and runs nothing.

State is said in words with a symbol beside it; colour is only an extra (a colour-blind
reader, a black-and-white print). The same holds on the timelines: each kind of mark has
its own shape, and every mark carries its words in an SVG <title> (a tooltip, and what a
screen reader reads).

Pure and fast: a hundred cars over a month is one string built from a list and joined once
(bench/fleetpage.py times it).
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from datetime import datetime, timedelta, timezone

from reconciler.base.text import printable
from reconciler.report.fleetview import STATES, CarView, FleetView, Mark, State, ago

WIDTH = 1000  # the timelines' viewBox width: one unit is the narrowest mark drawn
MIN_WIDTH = 1.0  # ran marks narrower than this are merged with their narrow neighbours
MARKER_ROW = 24  # the instants' row at the top of a timeline
LANE = 18  # one lane of ran bars per app (a bar 14 high, 4 between lanes)
MAX_LANES = 6  # the apps after the sixth share the last lane
LISTED = 5  # the labels a merged mark's <title> names before "and N more"

SYMBOLS: dict[State, str] = {"confirmed": "✓", "waiting": "…", "rolled back": "↺",
                             "unknown": "?"}
NOUNS = {"ran": ("run", "runs"), "rollback": ("rollback", "rollbacks"),
         "deferral": ("deferral", "deferrals"), "wait": ("wait", "waits"),
         "unknown": ("unknown stretch", "unknown stretches")}

CSS = """\
:root{--ok:#1a7f37;--wait:#9a6700;--bad:#cf222e;--unk:#57606a;--line:#d0d7de;
--fg:#1f2328;--bg:#fff;--muted:#57606a}
*{box-sizing:border-box}
body{font:15px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;color:var(--fg);
background:var(--bg);margin:0;padding:12px;max-width:1200px}
h1{font-size:1.35em;margin:.2em 0 .4em}h2{font-size:1.15em;margin:1.4em 0 .4em}
h3{font-size:1em;margin:1em 0 .2em}
dl.head{display:grid;grid-template-columns:max-content 1fr;gap:2px 12px;margin:0}
dl.head dt{font-weight:600}dl.head dd{margin:0}
.scroll{overflow-x:auto;-webkit-overflow-scrolling:touch;max-width:100%}
table{border-collapse:collapse;min-width:100%}
th,td{border-bottom:1px solid var(--line);padding:4px 8px;text-align:left;
vertical-align:top}
th{background:#f6f8fa;white-space:nowrap}.num{text-align:right}
caption{text-align:left}
code,.rev{font-family:ui-monospace,SFMono-Regular,Menlo,Consolas,monospace;font-size:.92em}
.state{white-space:nowrap;font-weight:600}td.detail{min-width:16em}
.sym{display:inline-block;width:1.2em;text-align:center}
.state-confirmed{color:var(--ok)}.state-waiting{color:var(--wait)}
.state-rolled-back{color:var(--bad)}.state-unknown{color:var(--unk)}
.timeline{margin:0 0 14px}.timeline svg{display:block;width:100%;height:auto;
border:1px solid var(--line);background:#fcfcfd}
.timeline .scroll>*{min-width:600px}
.axis{display:flex;justify-content:space-between;font-size:.8em;color:var(--muted)}
.note{font-size:.85em;color:var(--muted);margin:2px 0}
ul.legend{list-style:none;padding:0;margin:0}ul.legend li{margin:3px 0}
ul.legend svg{width:22px;height:22px;vertical-align:middle}
.ran{fill:#4f83cc;stroke:#fff;stroke-width:.5}.ran.lane1{fill:#8a63d2}
.ran.lane2{fill:#2da44e}.ran.lane3{fill:#bf8700}.ran.lane4{fill:#6e7781}
.ran.lane5{fill:#1b7c83}.ran.merged{fill-opacity:.6}
.m-rollback{fill:var(--bad)}.m-rollback line{stroke:var(--bad);stroke-width:1.5}
.m-deferral{fill:var(--wait)}.m-wait{fill:none;stroke:#0969da;stroke-width:2.5}
.m-wait rect{fill:#0969da;stroke:none;fill-opacity:.3}
.m-unknown{fill:var(--unk)}.band{fill-opacity:.3}
.tick{stroke:#eaeef2;stroke-width:1}
"""


def render(view: FleetView) -> str:
    """The page for `view`: header, a summary per desired revision, a row per car, a
    timeline per car, and the legend."""
    out: list[str] = [
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>Fleet report {_text(_short(view.tip))}</title>\n"
        f"<style>\n{CSS}</style>\n</head>\n<body>\n"]
    _header(view, out)
    _summary(view, out)
    _cars(view, out)
    _timelines(view, out)
    _legend(out)
    out.append("</body>\n</html>\n")
    return "".join(out)


def _header(view: FleetView, out: list[str]) -> None:
    counts = {s: 0 for s in STATES}
    for car in view.cars:
        counts[car.state] += 1
    said = " · ".join(f"{n} {s}" for s, n in counts.items() if n) or "no cars"
    out.append('<header>\n<h1>Fleet report</h1>\n<dl class="head">\n'
               f'<dt>Fleet tip</dt><dd><code class="rev">{_text(_short(view.tip))}</code>'
               "</dd>\n"
               f"<dt>Generated</dt><dd><time>{_iso(view.generated)}</time></dd>\n")
    if view.rollout is not None:
        out.append(f"<dt>Rollout</dt><dd>{_text(view.rollout)}</dd>\n")
    out.append(f"<dt>Timelines</dt><dd>{_when(view.since)} to {_when(view.generated)}</dd>\n"
               f"<dt>Cars</dt><dd>{len(view.cars)}: {said}</dd>\n</dl>\n</header>\n")


def _summary(view: FleetView, out: list[str]) -> None:
    out.append('<section id="revisions">\n<h2>By desired revision</h2>\n')
    if not view.revisions:
        out.append("<p>No car names a desired revision.</p>\n</section>\n")
        return
    out.append('<div class="scroll"><table>\n<caption class="note">How many cars stand '
               "where, for each revision the cars would apply</caption>\n<thead><tr>"
               '<th scope="col">Revision</th>'
               + "".join(f'<th scope="col" class="num">{name}</th>' for name in (
                   "Confirmed", "Waiting", "Failed (rolled back)", "Unknown", "Total"))
               + "</tr></thead>\n"
               "<tbody>\n")
    for r in view.revisions:
        total = r.confirmed + r.waiting + r.failed + r.unknown
        out.append(f'<tr><th scope="row"><code class="rev">{_text(r.revision[:12])}</code>'
                   f'</th><td class="num">{r.confirmed}</td><td class="num">{r.waiting}</td>'
                   f'<td class="num">{r.failed}</td><td class="num">{r.unknown}</td>'
                   f'<td class="num">{total}</td></tr>\n')
    out.append("</tbody>\n</table></div>\n</section>\n")


def _cars(view: FleetView, out: list[str]) -> None:
    out.append('<section id="cars">\n<h2>Cars</h2>\n')
    if not view.cars:
        out.append("<p>No car has reported yet.</p>\n</section>\n")
        return
    out.append('<div class="scroll"><table>\n<thead><tr><th scope="col">Vehicle</th>'
               '<th scope="col">State</th><th scope="col">Detail</th>'
               '<th scope="col">Revision</th><th scope="col">Apps</th>'
               '<th scope="col">Gate</th><th scope="col">Override</th>'
               '<th scope="col">Last report</th></tr></thead>\n<tbody>\n')
    for car in view.cars:
        vehicle = _text(car.vehicle)
        reported = "never" if car.reported is None else \
            f'<time datetime="{_iso(car.reported)}">' \
            f"{ago((view.generated - car.reported).total_seconds())}</time>"
        out.append(
            f'<tr id="car-{vehicle}" data-state="{car.state}">'
            f'<th scope="row"><a href="#timeline-{vehicle}">{vehicle}</a></th>'
            f'<td>{_state(car.state)}</td><td class="detail">{_text(car.detail)}</td>'
            f'<td><code class="rev">{_text(_short(car.revision))}</code></td>'
            f"<td>{'<br>'.join(_text(a) for a in car.apps) or 'none'}</td>"
            f"<td>{_text(car.gate or '-')}</td><td>{_text(car.override or '-')}</td>"
            f"<td>{reported}</td></tr>\n")
    out.append("</tbody>\n</table></div>\n</section>\n")


def _state(state: State) -> str:
    """The state as text with its symbol; the symbol is hidden from screen readers, which
    read the word."""
    return (f'<span class="state state-{state.replace(" ", "-")}">'
            f'<span class="sym" aria-hidden="true">{SYMBOLS[state]}</span> {state}</span>')


def _timelines(view: FleetView, out: list[str]) -> None:
    if not view.cars:
        return
    out.append('<section id="timelines">\n<h2>Timelines</h2>\n'
               f'<p class="note">From {_when(view.since)} to {_when(view.generated)}; '
               "each app runs in its own lane, instants are marked above the lanes. Hover "
               "or tap a mark for its words.</p>\n")
    scale = Scale(view.since, view.generated)
    ticks = "".join(f'<line class="tick" x1="{x:.1f}" x2="{x:.1f}" y1="0" y2="{{h}}"/>'
                    for x in scale.days())
    for car in view.cars:
        _timeline(car, scale, ticks, out)
    out.append("</section>\n")


class Scale:
    """Times to x in the timelines' viewBox: `since` at 0, `generated` at WIDTH; a time
    outside is drawn at the nearer edge."""

    def __init__(self, since: datetime, until: datetime) -> None:
        self.since = since
        self.until = until
        self.per_second = WIDTH / max((until - since).total_seconds(), 1.0)

    def x(self, when: datetime | None) -> float:
        if when is None:
            return float(WIDTH)
        return min(max((when - self.since).total_seconds() * self.per_second, 0.0), WIDTH)

    def days(self) -> list[float]:
        """Where each midnight (UTC) falls, thinned to at most 31 lines."""
        first = _utc(self.since).replace(hour=0, minute=0, second=0, microsecond=0)
        count = int((self.until - first).total_seconds() // 86400) + 1
        step = max(1, -(-count // 31))
        return [self.x(first + timedelta(days=d)) for d in range(1, count + 1, step)
                if first + timedelta(days=d) < self.until]


def _timeline(car: CarView, scale: Scale, ticks: str, out: list[str]) -> None:
    """One car's timeline: a lane of bars per app, and the instants above them. On a
    phone it is at least 600 px wide and scrolls sideways: at 400 px a month's lanes would
    be a few pixels high.

    Why marks are merged: a month is 1000 units wide, so a mark narrower than one unit is
    narrower than a pixel on any screen. Drawing each one costs bytes and time and shows
    nothing more, and a car whose app flapped every few minutes would make a page of tens
    of thousands of elements. So narrow runs next to each other become one bar, and
    deferrals, waits and unknown stretches that fall on the same unit become one marker;
    either says how many it stands for in its <title>. That bounds a car's elements by the
    width, whatever the car reports. Rollbacks are never merged: each one is what the
    page is read for.
    """
    vehicle = _text(car.vehicle)
    lanes: dict[str, int] = {}
    for m in car.marks:
        if m.kind == "ran":
            lanes.setdefault(_app(m.label), min(len(lanes), MAX_LANES - 1))
    height = MARKER_ROW + 4 + LANE * max(1, max(lanes.values(), default=0) + 1)
    counts = {k: 0 for k in NOUNS}
    for m in car.marks:
        counts[m.kind] += 1
    said = ", ".join(_counted(n, k) for k, n in counts.items() if n) or "nothing recorded"
    out.append(f'<div class="timeline" id="timeline-{vehicle}">\n<h3>{vehicle} '
               f"{_state(car.state)}</h3>\n"
               '<div class="scroll"><svg xmlns="http://www.w3.org/2000/svg" '
               f'viewBox="0 0 {WIDTH} {height}" '
               f'role="img" aria-label="Timeline of {vehicle}: {said}" '
               f'data-vehicle="{vehicle}">'
               f"<title>Timeline of {vehicle}: {said}</title>"
               + ticks.replace("{h}", str(height)))
    pending: dict[int, tuple[list[Mark], float]] = {}  # per lane: narrow runs, their end
    for m in car.marks:
        if m.kind != "ran":
            continue
        lane = lanes[_app(m.label)]
        x0, x1 = scale.x(m.start), scale.x(m.end)
        narrow, end = pending.get(lane, ([], 0.0))
        if narrow and (x1 - x0 >= MIN_WIDTH or x0 - end > MIN_WIDTH):
            _ran(narrow, lane, scale, out)
            narrow = []
        if x1 - x0 >= MIN_WIDTH:
            _ran([m], lane, scale, out)
            pending.pop(lane, None)
        else:
            narrow.append(m)
            pending[lane] = (narrow, max(x1, x0 + MIN_WIDTH))
    for lane, (narrow, _) in pending.items():
        if narrow:
            _ran(narrow, lane, scale, out)
    buckets: dict[tuple[str, int], list[Mark]] = {}
    for m in car.marks:
        if m.kind not in ("ran", "rollback"):
            buckets.setdefault((m.kind, int(scale.x(m.start))), []).append(m)
    for group in buckets.values():
        _marker(group, scale, height, out)
    for m in car.marks:  # last: drawn over everything else
        if m.kind == "rollback":
            _marker([m], scale, height, out)
    names = list(lanes)
    out.append(f'</svg>\n<div class="axis"><span>{_when(scale.since)}</span>'
               f"<span>{_when(scale.until)}</span></div></div>\n"
               f'<p class="note">{said.capitalize()}'
               + (f"; lanes, top to bottom: {_text(', '.join(names[:MAX_LANES]))}"
                  + (f" (the last also {_text(', '.join(names[MAX_LANES:]))})"
                     if len(names) > MAX_LANES else "") if names else "")
               + "</p>\n</div>\n")


def _ran(marks: Sequence[Mark], lane: int, scale: Scale, out: list[str]) -> None:
    """One bar: a run, or narrow runs merged (their count and labels in its title)."""
    first, last = marks[0], marks[-1]
    x0 = scale.x(first.start)
    x1 = max(scale.x(last.end), x0 + MIN_WIDTH)
    y = MARKER_ROW + 4 + lane * LANE
    if len(marks) == 1:
        title = f"{_text(first.label)}: {_span(first)}"
        merged = ""
    else:
        title = (f"{len(marks)} short runs, {_when(first.start)} to {_until(last.end)}: "
                 f"{_listed(marks)}")
        merged = " merged"
    out.append(f'<rect class="ran lane{lane}{merged}" data-kind="ran" x="{x0:.1f}" '
               f'y="{y}" width="{min(x1, WIDTH) - x0:.1f}" height="14"><title>{title}'
               "</title></rect>")


def _marker(marks: Sequence[Mark], scale: Scale, height: int, out: list[str]) -> None:
    """An instant (or a stretch, for a wait or an unknown with an end) as its own shape:
    rollback a triangle pointing down with a line through the lanes, deferral a diamond,
    wait a ring, unknown a square."""
    first = marks[0]
    kind = first.kind
    x = scale.x(first.start)
    if len(marks) == 1:
        title = f"{NOUNS[kind][0]} {_span(first)}: {_text(first.label)}"
    else:
        title = f"{_counted(len(marks), kind)} at {_when(first.start)}: {_listed(marks)}"
    band = ""
    if len(marks) == 1 and first.end != first.start:
        x1 = scale.x(first.end)
        band = f'<rect class="band" x="{x:.1f}" y="9" width="{x1 - x:.1f}" height="6"/>'
    out.append(f'<g class="m-{kind}" data-kind="{kind}"><title>{title}</title>{band}'
               f"{_shape(kind, x, height)}</g>")


def _shape(kind: str, x: float, height: int = MARKER_ROW) -> str:
    if kind == "rollback":
        return (f'<line x1="{x:.1f}" x2="{x:.1f}" y1="20" y2="{height}"/>'
                f'<path d="M{x - 7:.1f} 4H{x + 7:.1f}L{x:.1f} 20Z"/>')
    if kind == "deferral":
        return f'<path d="M{x:.1f} 4L{x + 7:.1f} 12L{x:.1f} 20L{x - 7:.1f} 12Z"/>'
    if kind == "wait":
        return f'<circle cx="{x:.1f}" cy="12" r="6"/>'
    return f'<rect x="{x - 6:.1f}" y="6" width="12" height="12"/>'


def _legend(out: list[str]) -> None:
    out.append('<section id="legend">\n<h2>Legend</h2>\n<ul class="legend">\n')
    for state in STATES:
        out.append(f"<li>{_state(state)}: {STATE_WORDS[state]}</li>\n")
    for kind, words in MARK_WORDS.items():
        if kind == "ran":
            shape = '<rect class="ran" x="0" y="6" width="24" height="12"/>'
        else:
            shape = f'<g class="m-{kind}">{_shape(kind, 12.0)}</g>'
        out.append(f'<li><svg viewBox="0 0 24 24" aria-hidden="true">{shape}</svg> '
                   f"{words}</li>\n")
    out.append("</ul>\n<p class=\"note\">A paler bar stands for several runs too short to "
               "draw apart; its tooltip counts and names them.</p>\n</section>\n")


STATE_WORDS: dict[State, str] = {
    "confirmed": "runs the revision it applied, its health proven",
    "waiting": "a revision is staged and waits for a gate, its wave's turn, or a halted "
               "rollout",
    "rolled back": "its last attempt failed or was rolled back; it runs what it ran before",
    "unknown": "no report for longer than the fleet expects, or one lpam cannot read"}
MARK_WORDS = {"ran": "bar: an app ran (one lane per app)",
              "rollback": "triangle down, with a line through the lanes: a rollback",
              "deferral": "diamond: an update deferred (a gate held it)",
              "wait": "ring: waited (for a gate, a wave or a halted rollout)",
              "unknown": "square: no readable report"}


def _text(value: str) -> str:
    """A car's words made safe in HTML text and in a quoted attribute: control characters
    replaced (they are not allowed in HTML), then escaped, quotes too."""
    return html.escape(value if value.isprintable() else printable(value))


def _short(revision: str | None) -> str:
    return "none" if revision is None else revision[:12]


def _app(label: str) -> str:
    """The app of a ran mark's `app@generation` label: its lane."""
    return label.partition("@")[0]


def _counted(number: int, kind: str) -> str:
    one, many = NOUNS[kind]
    return f"{number} {one if number == 1 else many}"


def _listed(marks: Sequence[Mark]) -> str:
    labels = "; ".join(_text(m.label) for m in marks[:LISTED])
    return labels + (f"; and {len(marks) - LISTED} more" if len(marks) > LISTED else "")


def _span(mark: Mark) -> str:
    if mark.end == mark.start:
        return f"at {_when(mark.start)}"
    return f"{_when(mark.start)} to {_until(mark.end)}"


def _until(end: datetime | None) -> str:
    return "now (still runs)" if end is None else _when(end)


def _utc(when: datetime) -> datetime:
    """`when` in UTC; a time without a zone is taken as UTC (the page says UTC)."""
    return when.replace(tzinfo=timezone.utc) if when.tzinfo is None \
        else when.astimezone(timezone.utc)


def _when(when: datetime) -> str:
    """`2026-11-20 05:42 UTC`; isoformat, not strftime: a page calls it for every mark."""
    return f"{_utc(when).isoformat(' ', 'minutes')[:16]} UTC"


def _iso(when: datetime) -> str:
    return _utc(when).isoformat(timespec="seconds").replace("+00:00", "Z")
