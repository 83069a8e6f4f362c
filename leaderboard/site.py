"""The static leaderboard site: plain HTML pages that work from ``file://`` without a server.

Why static and inline: the site is opened from a results checkout or a CI artefact, where there
is no server and browsers refuse ``fetch`` of local files. So every number is written into the
HTML itself (tables rendered here; the small script only sorts and filters existing rows), every
link is relative, and every image or GIF the pages show is copied into the site directory, which
can then be zipped or moved as a whole. All text coming from results files is escaped.

Layout of ``<site>``::

    index.html                   Table 1 (sortable, filterable), status, Figure 2
    runs/index.html              every run with its status
    runs/<run_id>.html           one run: metrics, per-norm functions, config, curve, MLflow, error
    scenarios/<Scenario>.html    layout, variants, radars, per-variant breakdown, episode GIFs
    assets/ figures/ gifs/ scenarios/img/ runs/img/

The directory is rebuilt from scratch into a temporary sibling and swapped in at the end, so a
failed build leaves the previous site intact; a directory that was not made by this module is
never deleted (it must carry the marker file).
"""

from __future__ import annotations

import html
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd

from leaderboard.aggregate import (
    ORACLE_BEST,
    ORACLE_WORST,
    RANDOM_EXACT,
    STD_DDOF,
    Group,
    Leaderboard,
    safe_name,
)
from leaderboard.figures import FigureSet, chain_title, norm_abbreviation, norm_label
from leaderboard.tables import fmt

SITE_MARKER = ".leaderboard-site"
#: |ours - paper| from which the difference is highlighted on the site.
NOTABLE_DELTA = 0.05
Progress = Callable[[Iterable[Any], str, int], Iterable[Any]]


class SiteError(RuntimeError):
    """The site cannot be built where asked (e.g. the target is a directory we did not create)."""


def h(value: Any) -> str:
    """HTML-escape any value (quotes too, so the result is safe in attributes)."""
    return html.escape("" if value is None else str(value), quote=True)


# ---------------------------------------------------------------------------------------- page frame
CSS = """
:root { --ink:#1d2330; --muted:#5b6475; --line:#dde1e8; --bg:#f5f6f8; --card:#fff; --accent:#1f5fae;
        --best:#e5f4ea; --warn:#b45309; --warnbg:#fff4e0; --bad:#b42318; --badbg:#fdecea; }
* { box-sizing: border-box; }
html { -webkit-text-size-adjust: 100%; }
body { margin:0; font:14px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;
       color:var(--ink); background:var(--bg); }
a { color:var(--accent); text-decoration:none; } a:hover { text-decoration:underline; }
code, pre, .mono { font-family: ui-monospace,SFMono-Regular,Menlo,Consolas,monospace; font-size:12.5px; }
header.top { background:#1d2a3f; color:#fff; padding:18px 28px 16px; }
header.top h1 { margin:0; font-size:22px; font-weight:650; letter-spacing:.2px; }
header.top .sub { margin:4px 0 0; color:#c5cede; font-size:13px; }
header.top a { color:#cfe0ff; }
nav.crumbs { font-size:13px; margin-bottom:6px; }
main { max-width:1480px; margin:0 auto; padding:18px 28px 40px; }
section.card { background:var(--card); border:1px solid var(--line); border-radius:8px; padding:16px 20px;
               margin:0 0 18px; }
h2 { font-size:17px; margin:0 0 10px; } h3 { font-size:15px; margin:16px 0 8px; }
p.note { color:var(--muted); font-size:12.5px; margin:6px 0 10px; max-width:980px; }
.stats { display:flex; flex-wrap:wrap; gap:10px; margin:0 0 10px; }
.stat { border:1px solid var(--line); border-radius:6px; padding:8px 14px; min-width:130px; background:#fafbfc; }
.stat .num { display:block; font-size:22px; font-weight:650; font-variant-numeric:tabular-nums; }
.stat .lbl { color:var(--muted); font-size:12px; }
.stat.warn { border-color:#f3c98b; background:var(--warnbg); } .stat.warn .num { color:var(--warn); }
.stat.bad { border-color:#f1b5ae; background:var(--badbg); } .stat.bad .num { color:var(--bad); }
.stat.good .num { color:#157f3b; }
details { margin:8px 0; } summary { cursor:pointer; font-weight:600; }
.controls { display:flex; flex-wrap:wrap; align-items:flex-end; gap:12px; margin:4px 0 10px; }
.controls label { display:flex; flex-direction:column; font-size:12px; color:var(--muted); gap:2px; }
.controls select { font:inherit; font-size:13px; padding:4px 6px; border:1px solid #c4cad4; border-radius:5px;
                   background:#fff; color:var(--ink); min-width:150px; }
.controls button { font:inherit; font-size:13px; padding:4px 10px; border:1px solid #c4cad4; border-radius:5px;
                   background:#fff; cursor:pointer; }
.controls .count { color:var(--muted); font-size:12.5px; margin-left:auto; }
.table-wrap { overflow-x:auto; }
table { border-collapse:collapse; width:100%; font-size:13px; }
th, td { padding:5px 9px; border-bottom:1px solid var(--line); text-align:left; vertical-align:middle; }
thead th { background:#eef1f5; font-weight:600; white-space:nowrap; position:sticky; top:0; z-index:1; }
th button { all:unset; cursor:pointer; display:inline-flex; gap:4px; align-items:center; }
th button:focus-visible { outline:2px solid var(--accent); outline-offset:2px; }
th button::after { content:"↕"; color:#9aa3b2; font-size:11px; }
th[aria-sort=ascending] button::after { content:"▲"; color:var(--ink); }
th[aria-sort=descending] button::after { content:"▼"; color:var(--ink); }
tbody tr:nth-child(even) { background:#fafbfc; } tbody tr:hover { background:#f0f5fc; }
tr[hidden] { display:none; }
td.num, th.num { text-align:right; font-variant-numeric:tabular-nums; white-space:nowrap; }
td.best { background:var(--best); font-weight:700; }
td.ref { color:#4a5568; background:#f7f8fa; }
td.off { color:var(--warn); font-weight:600; }
td.incomplete, span.incomplete { color:var(--warn); }
.muted { color:var(--muted); } .small { font-size:12px; }
.dot { display:inline-block; width:10px; height:10px; border-radius:50%; margin-right:6px; vertical-align:0;
       border:1px solid rgba(0,0,0,.15); }
.sweep { color:var(--muted); font-size:12px; white-space:nowrap; }
td.learner { white-space:nowrap; }
.badge { display:inline-block; padding:1px 8px; border-radius:10px; font-size:12px; font-weight:600; }
.badge.ok { background:#e3f4e8; color:#157f3b; } .badge.failed { background:var(--badbg); color:var(--bad); }
.badge.incomplete { background:var(--warnbg); color:var(--warn); font-weight:600; white-space:nowrap; }
.badge.submitted { background:#e8eefc; color:#2747a8; margin-left:6px; white-space:nowrap; }
.error { color:var(--bad); }
pre { background:#f6f8fa; border:1px solid var(--line); border-radius:6px; padding:10px 12px; overflow:auto;
      max-height:460px; margin:6px 0; }
pre.ascii { line-height:1.15; font-size:15px; display:inline-block; padding:10px 16px; }
.figs { display:grid; grid-template-columns:repeat(auto-fill,minmax(560px,1fr)); gap:14px; }
.figs.small { grid-template-columns:repeat(auto-fill,minmax(300px,1fr)); }
figure { margin:0; background:#fff; border:1px solid var(--line); border-radius:6px; padding:8px; }
figure img { max-width:100%; height:auto; display:block; margin:0 auto; }
figcaption { color:var(--muted); font-size:12px; margin-top:4px; }
.row { display:flex; flex-wrap:wrap; gap:16px; align-items:flex-start; }
.row > figure { max-width:min(100%, 640px); }
.seeds a, .seeds span { margin-right:5px; font-size:11.5px; }
.seeds .failed { color:var(--bad); } .seeds .missing { color:var(--warn); }
.pill { display:inline-block; border:1px solid var(--line); border-radius:12px; padding:2px 10px; margin:2px 4px 2px 0;
        background:#fafbfc; }
dl.kv { display:grid; grid-template-columns:max-content 1fr; gap:3px 16px; margin:0; }
dl.kv dt { color:var(--muted); } dl.kv dd { margin:0; font-variant-numeric:tabular-nums; }
footer { color:var(--muted); font-size:12px; text-align:center; padding:8px 0 24px; }
@media (max-width:700px) { main { padding:12px; } header.top { padding:14px; } .figs { grid-template-columns:1fr; } }
"""

JS = """
"use strict";
(function () {
  function keyOf(row, col, type) {
    var cell = row.cells[col];
    if (!cell) return null;
    var raw = cell.getAttribute("data-sort");
    if (raw === null) raw = cell.textContent.trim();
    if (type === "num") {
      var v = parseFloat(raw);
      return isNaN(v) ? null : v;
    }
    return raw === "" ? null : raw.toLowerCase();
  }

  function setupSort(table) {
    var tbody = table.tBodies[0];
    var headers = table.tHead.rows[0].cells;
    var rows = Array.prototype.slice.call(tbody.rows);
    rows.forEach(function (row, i) { row.setAttribute("data-index", String(i)); });
    var state = { col: -1, dir: 1 };
    function sortBy(col) {
      var type = headers[col].getAttribute("data-type") || "text";
      if (state.col === col) { state.dir = -state.dir; } else { state.dir = type === "num" ? -1 : 1; }
      state.col = col;
      var idx = function (r) { return Number(r.getAttribute("data-index")); };
      var sorted = rows.slice().sort(function (a, b) {
        var ka = keyOf(a, col, type), kb = keyOf(b, col, type);
        if (ka === null || kb === null) {
          if (ka === kb) return idx(a) - idx(b);
          return ka === null ? 1 : -1;  /* empty cells last in both directions */
        }
        var c = type === "num" ? ka - kb : ka.localeCompare(kb);
        return c !== 0 ? c * state.dir : idx(a) - idx(b);
      });
      sorted.forEach(function (r) { tbody.appendChild(r); });
      for (var i = 0; i < headers.length; i++) {
        if (headers[i].querySelector("button")) {
          headers[i].setAttribute("aria-sort", i === col ? (state.dir > 0 ? "ascending" : "descending") : "none");
        }
      }
    }
    Array.prototype.forEach.call(headers, function (th, col) {
      var button = th.querySelector("button");
      if (button) button.addEventListener("click", function () { sortBy(col); });
    });
  }

  function setupFilters(table) {
    var id = table.id;
    var selects = Array.prototype.slice.call(document.querySelectorAll('select[data-table="' + id + '"]'));
    if (!selects.length) return;
    var rows = Array.prototype.slice.call(table.tBodies[0].rows);
    var count = document.querySelector('[data-count="' + id + '"]');
    var empty = document.querySelector('[data-empty="' + id + '"]');
    function apply() {
      var shown = 0;
      rows.forEach(function (row) {
        var ok = selects.every(function (sel) {
          return !sel.value || row.getAttribute("data-" + sel.getAttribute("data-filter")) === sel.value;
        });
        row.hidden = !ok;
        if (ok) shown += 1;
      });
      if (count) count.textContent = "Showing " + shown + " of " + rows.length + " rows";
      if (empty) empty.hidden = shown !== 0;
      selects.forEach(function (sel) {
        var name = sel.getAttribute("data-filter");
        document.querySelectorAll('[data-section-' + name + ']').forEach(function (section) {
          section.hidden = !!sel.value && section.getAttribute("data-section-" + name) !== sel.value;
        });
      });
    }
    selects.forEach(function (sel) { sel.addEventListener("change", apply); });
    var reset = document.querySelector('button[data-reset="' + id + '"]');
    if (reset) reset.addEventListener("click", function () {
      selects.forEach(function (sel) { sel.value = sel.getAttribute("data-default") || ""; });
      apply();
    });
    apply();
  }

  Array.prototype.forEach.call(document.querySelectorAll("table.sortable"), function (table) {
    setupSort(table);
    setupFilters(table);
  });
})();
"""


def page(title: str, body: str, root: str, subtitle: str = "", crumbs: str = "") -> str:
    """A complete HTML document; ``root`` is the relative path back to the site root ("" or "../")."""
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{h(title)}</title>
<link rel="icon" href="data:,">
<link rel="stylesheet" href="{root}assets/site.css">
</head>
<body>
<header class="top">
{crumbs}<h1>{h(title)}</h1>
{f'<p class="sub">{subtitle}</p>' if subtitle else ''}
</header>
<main>
{body}
</main>
<footer>MoralityGym leaderboard · static site built {h(stamp)} by <code>python -m leaderboard.build</code></footer>
<script src="{root}assets/site.js"></script>
</body>
</html>
"""


def num_td(value: Any, digits: int = 3, signed: bool = False, classes: str = "", bold: bool = False,
           suffix: str = "") -> str:
    """A numeric cell with its exact value in ``data-sort`` (blank when missing: sorts last).

    ``suffix``: HTML appended after the number (e.g. the incomplete badge).
    """
    missing = value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value))
    sort = "" if missing else repr(float(value))
    text = h(fmt(value, digits, signed))
    if bold and not missing:
        text = f"<strong>{text}</strong>"
    cls = f"num {classes}".strip()
    return f'<td class="{cls}" data-sort="{sort}">{text}{suffix}</td>'


def incomplete_badge(reason: str) -> str:
    """The mark of an incomplete cell: a ⚠ whose tooltip says what is lacking."""
    return f' <span class="badge incomplete" title="incomplete: {h(reason)}">⚠ incomplete</span>'


def submitted_badge(note: str) -> str:
    """The mark of an entry submitted from outside (``leaderboard.submit``), not trained by a sweep."""
    return f' <span class="badge submitted" title="{h(note)}">submitted</span>'


def _expected_count(record: dict[str, Any]) -> int:
    """The cell's expected number of runs (variants x seeds), or its planned count if unknown."""
    value = record.get("n_expected")
    if value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value)) or int(value) == 0:
        return int(record["n_planned"])
    return int(value)


def sort_th(label: str, kind: str = "text", title: str = "") -> str:
    cls = ' class="num"' if kind == "num" else ""
    tip = f' title="{h(title)}"' if title else ""
    return f'<th data-type="{kind}" aria-sort="none"{cls}{tip}><button type="button">{h(label)}</button></th>'


def dot(colour: str) -> str:
    return f'<span class="dot" style="background:{h(colour)}"></span>'


# ---------------------------------------------------------------------------------------- links
def run_href(run_id: str, root: str) -> str:
    return f"{root}runs/{safe_name(run_id)}.html"


def scenario_href(scenario: str, root: str, anchor: str = "") -> str:
    return f"{root}scenarios/{safe_name(scenario)}.html" + (f"#{anchor}" if anchor else "")


def section_id(group: Group, chain: str) -> str:
    return f"{group.slug}--{safe_name(chain)}"


# ---------------------------------------------------------------------------------------- site state
@dataclass
class SiteBuild:
    """What the page writers share: inputs, and which assets ended up in the site."""

    lb: Leaderboard
    results_dir: Path
    results_name: str
    figures: FigureSet
    out: Path
    gifs: dict[str, str] = field(default_factory=dict)  # run id -> path relative to site root
    layouts: dict[str, str] = field(default_factory=dict)  # scenario -> image path relative to site root
    layout_notes: dict[str, str] = field(default_factory=dict)  # scenario -> why there is no image
    learn: dict[str, str] = field(default_factory=dict)  # run id -> curve path relative to site root
    updates: dict[str, str] = field(default_factory=dict)  # run id -> diagnostics image relative to site root
    pages: int = 0

    def colour(self, learner: str) -> str:
        return self.figures.colours.get(learner, "#999999")


def _copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)


def _inside(path: Path, root: Path) -> bool:
    try:
        path.resolve().relative_to(root.resolve())
        return True
    except ValueError:
        return False


def copy_figures(sb: SiteBuild) -> None:
    """Copy the figures the pages show into ``figures/`` and the learn curves into ``runs/img``."""
    for (group, chain), path in sb.figures.bars.items():
        _copy(path, sb.out / "figures" / group.slug / path.name)
    for (group, chain, scenario), path in sb.figures.radars.items():
        _copy(path, sb.out / "figures" / group.slug / path.name)
    for run_id, path in sb.figures.learn.items():
        if path.is_file():
            target = f"runs/img/{safe_name(run_id)}.png"
            _copy(path, sb.out / target)
            sb.learn[run_id] = target
    for run_id, path in sb.figures.updates.items():
        if path.is_file():
            target = f"runs/img/{safe_name(run_id)}.updates.png"
            _copy(path, sb.out / target)
            sb.updates[run_id] = target


def gif_choices(lb: Leaderboard, results_dir: Path) -> dict[tuple[Group, str, str, str], dict[str, Any]]:
    """One evaluation-episode GIF per (group, chain, scenario, learner): first variant, lowest seed.

    Only runs whose GIF exists inside the results directory qualify (a path pointing elsewhere is
    ignored rather than copied: the site must not pick up arbitrary files).
    """
    from morality_gym.envs.registry import scenario_named

    chosen: dict[tuple[Group, str, str, str], dict[str, Any]] = {}
    runs = lb.runs.loc[lb.runs["ok"] & lb.runs["gif_path"].notna()]
    variant_rank: dict[str, dict[str, int]] = {}
    for record in runs.to_dict("records"):
        scenario = str(record["scenario"])
        if scenario not in variant_rank:
            try:
                variant_rank[scenario] = {v: i for i, v in enumerate(scenario_named(scenario).variants)}
            except KeyError:
                variant_rank[scenario] = {}
        path = results_dir / str(record["gif_path"])
        if not path.is_file() or not _inside(path, results_dir):
            continue
        key = (Group(record["protocol"], record["preset"]), str(record["chain"]), scenario, str(record["learner"]))
        rank = (variant_rank[scenario].get(record["variant"], 999), str(record["variant"]), int(record["seed"]))
        if key not in chosen or rank < chosen[key]["_rank"]:
            chosen[key] = record | {"_rank": rank, "_path": path}
    return chosen


def copy_gifs(sb: SiteBuild, choices: dict[tuple[Group, str, str, str], dict[str, Any]]) -> None:
    for record in choices.values():
        target = f"gifs/{safe_name(str(record['run_id']))}.gif"
        _copy(record["_path"], sb.out / target)
        sb.gifs[str(record["run_id"])] = target


def render_layouts(sb: SiteBuild, scenarios: list[str]) -> None:
    """A PNG of each scenario's initial state (first variant); the reason when it cannot be drawn."""
    try:
        from PIL import Image

        from morality_gym.envs.trolley import TrolleyEnv
        from morality_gym.render.rgb import render_rgb
    except Exception as exc:  # noqa: BLE001 - the renderer may be unfinished; the ASCII picture remains
        for scenario in scenarios:
            sb.layout_notes[scenario] = f"rendering unavailable ({type(exc).__name__}: {exc}); ASCII picture only"
        return
    from morality_gym.envs.registry import scenario_named

    for scenario in scenarios:
        try:
            env_id = scenario_named(scenario).env_ids[0]
            env = TrolleyEnv(env_id)
            env.reset(seed=0)
            frame = render_rgb(env.world, env.state, 40, caption=f"{env_id}, initial state")
            target = f"scenarios/img/{safe_name(scenario)}.png"
            (sb.out / target).parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(frame).save(sb.out / target)
            sb.layouts[scenario] = target
            env.close()
        except Exception as exc:  # noqa: BLE001 - reported on the page, the build goes on
            sb.layout_notes[scenario] = f"rendering failed ({type(exc).__name__}: {exc}); ASCII picture only"


# ---------------------------------------------------------------------------------------- index page
def _run_link(run_id: str, root: str) -> str:
    return f'<a class="mono" href="{h(run_href(run_id, root))}">{h(run_id)}</a>'


def _run_report(records: list[dict[str, Any]], root: str, *, linked: bool = False, table_id: str = "",
                extra: dict[str, Callable[[dict[str, Any]], str]] | None = None) -> str:
    """A table of runs for the status section: identity columns, then one cell per ``extra`` header.

    ``linked``: the run id links to its run page (only runs with a result have one).
    """
    extra = extra or {}
    head = "".join(f"<th>{x}</th>" for x in ("Run", "Sweep", "Chain", "Scenario", "Variant", "Learner"))
    head += '<th class="num">Seed</th>' + "".join(f"<th>{h(x)}</th>" for x in extra)
    rows = []
    for r in records:
        run = f'<td>{_run_link(str(r["run_id"]), root)}</td>' if linked else f'<td class="mono">{h(r["run_id"])}</td>'
        rows.append(f'<tr>{run}<td>{h(r["protocol"])} · {h(r["preset"])}</td><td>{h(r["chain"])}</td>'
                    f'<td>{h(r["scenario"])}</td><td>{h(r["variant"])}</td><td>{h(r["learner"])}</td>'
                    f'<td class="num">{h(_int(r["seed"]))}</td>' + "".join(cell(r) for cell in extra.values()) + "</tr>")
    table_attr = f' id="{table_id}"' if table_id else ""
    return (f'<div class="table-wrap"><table{table_attr}><thead><tr>{head}</tr></thead><tbody>'
            + "".join(rows) + "</tbody></table></div>")


def status_section(sb: SiteBuild, root: str) -> str:
    """Counts of runs, failures and missing runs, and the full lists (nothing hidden)."""
    lb = sb.lb
    n_failed, n_missing = len(lb.problems), len(lb.missing)
    n_planned = len(set(lb.planned) | set(lb.runs["run_id"]))
    learner_rows = lb.table.loc[lb.table["kind"] == "learner"]
    n_incomplete = int((~learner_rows["complete"].astype(bool)).sum()) if len(learner_rows) else 0
    stats = [
        ("good", lb.n_ok, "runs with a result"),
        ("bad" if n_failed else "", n_failed, "failed"),
        ("warn" if n_missing else "", n_missing, f"missing of {n_planned} planned"),
        *([("", len(lb.superseded), "superseded, not counted")] if len(lb.superseded) else []),
        *([("warn", n_incomplete, "incomplete cells (marked ⚠)")] if n_incomplete else []),
        *([("bad", len(lb.skipped), "unreadable files, left out")] if lb.skipped else []),
        ("", len(lb.pairs()), "(chain, scenario) rows"),
        ("", len(lb.groups), "sweeps (protocol · preset)"),
    ]
    parts = ['<section class="card" id="status"><h2>Status</h2><div class="stats">']
    for cls, value, label in stats:
        parts.append(f'<div class="stat {cls}"><span class="num">{h(value)}</span><span class="lbl">{h(label)}</span></div>')
    parts.append("</div>")
    parts.append(f'<p class="note">Sweeps: {", ".join(h(g.label) for g in lb.groups) or "none"}. '
                 f'<a href="{root}runs/index.html">All runs ({len(lb.runs)})</a>.</p>')
    if n_failed:
        parts.append(f'<h3 class="error">Failed runs ({n_failed})</h3>' + _run_report(
            lb.problems.to_dict("records"), root, linked=True, table_id="failed",
            extra={"Error": lambda r: f'<td class="error">{h(r["error"])}</td>'}))
    if n_missing:
        opened = " open" if n_missing <= 25 else ""
        parts.append(f'<details id="missing"{opened}><summary>Missing runs ({n_missing}): planned in a sweep manifest, '
                     'no result file</summary>' + _run_report(lb.missing.to_dict("records"), root) + "</details>")
    if not n_failed and not n_missing:
        parts.append('<p>Every planned run has a result.</p>')
    if len(lb.superseded):
        parts.append(f'<details id="superseded"><summary>Superseded runs ({len(lb.superseded)}): another configuration, '
                     'or another run of the same slot, counts instead (typically these ran with an earlier '
                     'configuration)</summary>'
                     + _run_report(lb.superseded.to_dict("records"), root, extra={
                         "Counted instead": lambda r: _counted_instead_td(r, root)})
                     + "</details>")
    if lb.skipped:
        items = "".join(f"<li><code>{h(i['file'])}</code>: {h(i['reason'])}</li>" for i in lb.skipped)
        parts.append(f'<div id="skipped"><h3 class="error">Unreadable files, left out ({len(lb.skipped)})</h3>'
                     '<p class="note">Their runs count as missing where planned; a sweep over the same runs moves such '
                     f'files to <code>runs/.quarantine/</code> and runs them again.</p><ul>{items}</ul></div>')
    if lb.quarantined:
        items = "".join(f"<li><code>{h(i.get('file'))}</code> → <code>{h(i.get('moved_to'))}</code> "
                        f"({h(i.get('reason'))}, {h(i.get('at'))})</li>" for i in lb.quarantined)
        parts.append(f'<details id="quarantined"><summary>Files moved aside by sweeps ({len(lb.quarantined)}): '
                     'unreadable when found, kept in runs/.quarantine/ and run again</summary>'
                     f'<ul>{items}</ul></details>')
    if lb.reference_errors:
        items = "".join(f"<li><code>{h(k)}</code>: {h(v)}</li>" for k, v in lb.reference_errors.items())
        parts.append(f'<p class="error">Reference rows that could not be computed:</p><ul>{items}</ul>')
    parts.append("</section>")
    return "".join(parts)


def _counted_instead_td(record: dict[str, Any], root: str) -> str:
    other = record.get("superseded_by")
    if other is None or (isinstance(other, float) and math.isnan(other)):
        return '<td class="muted">— (another configuration is the cell\'s; no run of it for this slot yet)</td>'
    return f'<td>{_run_link(str(other), root)}</td>'


def _int(value: Any) -> str:
    try:
        return str(int(value))
    except (TypeError, ValueError):
        return "—"


def _options(name: str, values: list[tuple[str, str]], table: str, default: str = "", any_label: str = "all") -> str:
    opts = [f'<option value="">{h(any_label)}</option>']
    for value, label in values:
        selected = " selected" if value == default else ""
        opts.append(f'<option value="{h(value)}"{selected}>{h(label)}</option>')
    return (f'<label>{h(name)}<select data-table="{h(table)}" data-filter="{h(name.lower())}" '
            f'data-default="{h(default)}">{"".join(opts)}</select></label>')


def table1_section(sb: SiteBuild, root: str) -> str:
    """Table 1, long format: one row per (sweep, chain, scenario, learner), reference values alongside."""
    lb = sb.lb
    t = lb.table
    learners = t.loc[t["kind"] == "learner"]
    reference = {(r["protocol"], r["preset"], r["chain"], r["scenario"], r["learner"]): r["mean"]
                 for r in t.loc[t["kind"] == "reference"].to_dict("records")}
    default = lb.primary.slug if lb.primary else ""
    controls = ['<div class="controls">',
                _options("Sweep", [(g.slug, f"{g.protocol} · {g.preset}") for g in lb.groups], "table1", default, "all sweeps"),
                _options("Chain", [(c, c) for c in dict.fromkeys(c for c, _ in lb.pairs())], "table1"),
                _options("Scenario", [(s, s) for s in sorted({s for _, s in lb.pairs()})], "table1"),
                _options("Learner", [(name, name) for name in lb.learners], "table1"),
                '<button type="button" data-reset="table1">Reset filters</button>',
                '<span class="count" data-count="table1"></span></div>']
    head = "".join([
        sort_th("Sweep"), sort_th("Chain"), sort_th("Scenario"), sort_th("Learner"),
        sort_th("Ours", "num", "mean metric over all variants and seeds"),
        sort_th("± std", "num", "std over seeds of the per-seed means"),
        sort_th("Runs", "num", "runs with a result / expected (variants × seeds)"),
        sort_th("Paper", "num", "the paper's Table 1"), sort_th("Δ", "num", "ours − paper"),
        sort_th(RANDOM_EXACT, "num", "exact expected metric of the uniform random policy"),
        sort_th(ORACLE_BEST, "num", "best metric any policy can reach"),
        sort_th(ORACLE_WORST, "num", "worst metric any policy can reach"),
    ])
    body = []
    submitted = lb.submitted
    for r in learners.to_dict("records"):
        group = Group(r["protocol"], r["preset"])
        ref = [reference.get((r["protocol"], r["preset"], r["chain"], r["scenario"], name)) for name in
               (RANDOM_EXACT, ORACLE_BEST, ORACLE_WORST)]
        n, expected = int(r["n_runs"]), _expected_count(r)
        complete = bool(r["complete"])
        runs_cls = "" if complete else "incomplete"
        runs_title = "" if complete else f' title="incomplete: {h(r["incomplete_reason"])}"'
        delta = r["delta"]
        off = "off" if delta is not None and not math.isnan(delta) and abs(delta) >= NOTABLE_DELTA else ""
        href = scenario_href(r["scenario"], root, section_id(group, r["chain"]))
        mark = "" if complete else incomplete_badge(str(r["incomplete_reason"]))
        body.append(
            f'<tr data-sweep="{h(group.slug)}" data-chain="{h(r["chain"])}" data-scenario="{h(r["scenario"])}" '
            f'data-learner="{h(r["learner"])}" data-best="{int(bool(r["best"]))}" data-complete="{int(complete)}">'
            f'<td class="sweep">{h(r["protocol"])} · {h(r["preset"])}</td><td>{h(r["chain"])}</td>'
            f'<td><a href="{h(href)}">{h(r["scenario"])}</a></td>'
            f'<td class="learner">{dot(sb.colour(r["learner"]))}{h(r["learner"])}'
            f'{submitted_badge(submitted[r["learner"]]) if r["learner"] in submitted else ""}</td>'
            + num_td(r["mean"], classes="best" if r["best"] else runs_cls, bold=bool(r["best"]), suffix=mark)
            + num_td(r["std"])
            + f'<td class="num {runs_cls}" data-sort="{n}"{runs_title}>{n}/{expected}</td>'
            + num_td(r["paper"]) + num_td(delta, signed=True, classes=off)
            + "".join(num_td(v, classes="ref") for v in ref) + "</tr>")
    return (
        '<section class="card" id="table1-section"><h2>Table 1: average normalised morality metric</h2>'
        f'<p class="note">Ours = mean of the final evaluation\'s morality metric over all variants and seeds of the '
        f'scenario; ± = standard deviation over seeds of the per-seed means (ddof={STD_DDOF}). The best learner of '
        f'each (sweep, chain, scenario) is <strong>bold</strong>. Δ = ours − paper, highlighted from '
        f'|Δ| ≥ {NOTABLE_DELTA}. ⚠ incomplete (orange): fewer results than the scenario\'s variants times the preset\'s seeds; such a cell '
        f'is never bold and not compared with the paper (no Δ). {h(RANDOM_EXACT)}: exact expectation of '
        'the uniform random policy; oracle best/worst: the range any policy can reach (means over variants). '
        '<span class="badge submitted">submitted</span>: an external policy scored with <code>python -m '
        'leaderboard.submit</code> (same final evaluation as the trained runs; no training by the sweep). '
        'Click a column header to sort; click a scenario for its page.</p>'
        + "".join(controls)
        + '<div class="table-wrap"><table id="table1" class="sortable"><thead><tr>' + head + "</tr></thead><tbody>"
        + "".join(body) + "</tbody></table></div>"
        + '<p class="note" data-empty="table1" hidden>No row matches the filters.</p></section>')


def figure2_section(sb: SiteBuild, root: str) -> str:
    """Figure 2 per sweep (bars per chain); the sweep filter of Table 1 also picks the figures shown."""
    parts = [('<section class="card" id="figure2"><h2>Figure 2: morality function per norm</h2>'
             '<p class="note">Mean of each norm\'s morality function over the (scenario, variant, seed) runs in which '
             'the norm is relevant for the chain; error bars: std over seeds of the per-seed means. Norms in chain '
             'order, highest force first.</p>')]
    any_figure = False
    for group in sb.lb.groups:
        items = [(chain, path) for (g, chain), path in sb.figures.bars.items() if g == group]
        if not items:
            continue
        any_figure = True
        parts.append(f'<div data-section-sweep="{h(group.slug)}"><h3>{h(group.label)}</h3><div class="figs">')
        for chain, path in items:
            src = f"{root}figures/{group.slug}/{path.name}"
            parts.append(f'<figure><img src="{h(src)}" alt="{h("Figure 2 bars for " + chain + ", " + group.label)}" '
                         f'></figure>')
        parts.append("</div></div>")
    if not any_figure:
        parts.append("<p>No per-norm data yet (no run with a result).</p>")
    parts.append("</section>")
    return "".join(parts)


def scenarios_section(sb: SiteBuild, root: str) -> str:
    by_scenario: dict[str, list[str]] = {}
    for chain, scenario in sb.lb.pairs():
        by_scenario.setdefault(scenario, []).append(chain)
    items = "".join(
        f'<a class="pill" href="{h(scenario_href(s, root))}">{h(s)} <span class="muted small">'
        f'{h(", ".join(chains))}</span></a>' for s, chains in sorted(by_scenario.items()))
    return f'<section class="card" id="scenarios"><h2>Scenarios</h2><div>{items}</div></section>'


def index_page(sb: SiteBuild) -> str:
    lb = sb.lb
    primary = f"primary sweep: {h(lb.primary.label)}" if lb.primary else "no sweep"
    subtitle = (f"Reproduction of the MoralityGym paper's Table 1 and Figure 2 · results <code>{h(sb.results_name)}</code>"
                f" · {primary}")
    body = status_section(sb, "") + table1_section(sb, "") + figure2_section(sb, "") + scenarios_section(sb, "")
    return page("MoralityGym leaderboard", body, "", subtitle)


# ---------------------------------------------------------------------------------------- runs index
def runs_index_page(sb: SiteBuild) -> str:
    root = "../"
    runs = sb.lb.runs.sort_values(["protocol", "preset", "chain", "scenario", "variant", "learner", "seed"])
    rows = []
    for r in runs.to_dict("records"):
        status = "ok" if r["ok"] else "failed"
        rows.append(
            f'<tr data-status="{status}" data-learner="{h(r["learner"])}" data-chain="{h(r["chain"])}">'
            f'<td>{_run_link(str(r["run_id"]), root)}</td>'
            f'<td><span class="badge {status}">{h(r["status"])}</span></td>'
            f'<td class="sweep">{h(r["protocol"])} · {h(r["preset"])}</td><td>{h(r["chain"])}</td>'
            f'<td>{h(r["scenario"])}</td><td>{h(r["variant"])}</td>'
            f'<td>{dot(sb.colour(str(r["learner"])))}{h(r["learner"])}</td><td class="num">{h(_int(r["seed"]))}</td>'
            + num_td(r["metric"]) + "</tr>")
    controls = ('<div class="controls">'
                + _options("Status", [("ok", "ok"), ("failed", "failed")], "runs")
                + _options("Chain", [(c, c) for c in dict.fromkeys(c for c, _ in sb.lb.pairs())], "runs")
                + _options("Learner", [(n, n) for n in sb.lb.learners], "runs")
                + '<span class="count" data-count="runs"></span></div>')
    head = "".join([sort_th("Run"), sort_th("Status"), sort_th("Sweep"), sort_th("Chain"), sort_th("Scenario"),
                    sort_th("Variant"), sort_th("Learner"), sort_th("Seed", "num"), sort_th("Metric", "num")])
    body = (f'<section class="card"><h2>Runs ({len(runs)})</h2>{controls}<div class="table-wrap">'
            f'<table id="runs" class="sortable"><thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>'
            '</div><p class="note" data-empty="runs" hidden>No run matches the filters.</p></section>')
    crumbs = f'<nav class="crumbs"><a href="{root}index.html">← Leaderboard</a></nav>'
    return page("All runs", body, root, f"results <code>{h(sb.results_name)}</code>", crumbs)


# ---------------------------------------------------------------------------------------- scenario pages
def _variant_specs(scenario: str) -> tuple[Any, list[str]]:
    from morality_gym.envs.registry import scenario_named

    try:
        spec = scenario_named(scenario)
    except KeyError:
        return None, []
    return spec, list(spec.variants)


def layout_section(sb: SiteBuild, scenario: str, spec: Any) -> str:
    parts = ['<section class="card" id="layout"><h2>Layout</h2><div class="row">']
    first = next(iter(spec.variants)) if spec is not None else None
    if scenario in sb.layouts:
        parts.append(f'<figure><img src="../{h(sb.layouts[scenario])}" alt="{h("Initial state of " + scenario)}">'
                     f'<figcaption>Initial state of variant {h(first)} (rgb rendering)</figcaption></figure>')
    if spec is not None:
        picture = "\n".join(spec.picture(first))
        parts.append(f'<figure><pre class="ascii">{h(picture)}</pre><figcaption>ASCII picture of variant {h(first)}: '
                     'P agent, G landmark, T trolley, S switch, / lever, &lt; &gt; ^ v rails, # wall, h a r human '
                     'animal robot (capital: pushable)</figcaption></figure>')
    parts.append("</div>")
    if scenario in sb.layout_notes:
        parts.append(f'<p class="note">{h(sb.layout_notes[scenario])}</p>')
    parts.append("</section>")
    return "".join(parts)


def variants_section(spec: Any) -> str:
    if spec is None:
        return ('<section class="card"><h2>Variants</h2><p>This scenario is not registered in this checkout, '
                'so its variants cannot be described.</p></section>')
    rows = []
    for name, variant in spec.variants.items():
        chars = ", ".join(f"{n} {t}" for t, n in zip(variant.types, variant.amounts))
        relevant = " ".join(f'<span class="pill" title="{h(norm_label(n))}">{h(norm_abbreviation(n))}</span>'
                            for n in variant.relevant)
        rows.append(f'<tr><td>{h(name)}</td><td class="mono">{h(spec.env_id(name))}</td><td>{h(chars)}</td>'
                    f'<td>{relevant}</td></tr>')
    return ('<section class="card" id="variants"><h2>Variants</h2><div class="table-wrap"><table><thead><tr>'
            '<th>Variant</th><th>Env id</th><th>Characters</th><th>Salient norms (all chains)</th></tr></thead><tbody>'
            + "".join(rows) + "</tbody></table></div></section>")


def _summary_table(sb: SiteBuild, group: Group, chain: str, scenario: str) -> str:
    t = sb.lb.group_table(group)
    t = t.loc[(t["chain"] == chain) & (t["scenario"] == scenario)]
    rows = []
    for r in t.to_dict("records"):
        mark = ""
        if r["kind"] == "learner":
            runs = f'{int(r["n_runs"])}/{_expected_count(r)}'
            complete = bool(r["complete"])
            cls = ' class="num"' if complete else f' class="num incomplete" title="incomplete: {h(r["incomplete_reason"])}"'
            label = f'{dot(sb.colour(r["learner"]))}{h(r["learner"])}'
            if r["learner"] in sb.lb.submitted:
                label += submitted_badge(sb.lb.submitted[r["learner"]])
            mark = "" if complete else incomplete_badge(str(r["incomplete_reason"]))
        else:
            runs, cls, label = "exact", ' class="num muted"', f'<span class="muted">{h(r["learner"])}</span>'
        rows.append(f"<tr><td>{label}</td>"
                    + num_td(r["mean"], classes="best" if r["best"] else "", bold=bool(r["best"]), suffix=mark)
                    + num_td(r["std"]) + f"<td{cls}>{runs}</td>" + num_td(r["paper"]) + num_td(r["delta"], signed=True)
                    + "</tr>")
    return ('<table class="summary"><thead><tr><th>Learner</th><th class="num">Mean</th><th class="num">± std</th>'
            '<th class="num">Runs</th><th class="num">Paper</th><th class="num">Δ</th></tr></thead><tbody>'
            + "".join(rows) + "</tbody></table>")


def _breakdown_table(sb: SiteBuild, group: Group, chain: str, scenario: str, variant_names: list[str]) -> str:
    """Metric per variant (rows) and learner (columns), with seed links, and the reference values."""
    lb = sb.lb
    v = lb.variants
    v = v.loc[(v["protocol"] == group.protocol) & (v["preset"] == group.preset) & (v["chain"] == chain)
              & (v["scenario"] == scenario)]
    miss = lb.missing
    miss = miss.loc[(miss["protocol"] == group.protocol) & (miss["preset"] == group.preset) & (miss["chain"] == chain)
                    & (miss["scenario"] == scenario)]
    learners = [name for name in lb.learners if name in set(v["learner"]) | set(miss["learner"])]
    entry = lb.reference_entry(chain, scenario, group)
    names = [n for n in variant_names if n in set(v["variant"]) | set(miss["variant"])]
    names += sorted((set(v["variant"]) | set(miss["variant"])) - set(names))
    head = ("<tr><th>Variant</th>" + "".join(f'<th class="num">{dot(sb.colour(n))}{h(n)}</th>' for n in learners)
            + f'<th class="num">{h(RANDOM_EXACT)}</th><th class="num">{h(ORACLE_BEST)}</th>'
            f'<th class="num">{h(ORACLE_WORST)}</th></tr>')
    failed = set(lb.runs.loc[~lb.runs["ok"], "run_id"])
    rows = []
    for name in names:
        cells = [f"<td>{h(name)}</td>"]
        for learner in learners:
            part = v.loc[(v["variant"] == name) & (v["learner"] == learner)]
            missing_seeds = miss.loc[(miss["variant"] == name) & (miss["learner"] == learner), "seed"]
            links = []
            value = "—"
            sort = ""
            if not part.empty:
                r = part.iloc[0]
                if not math.isnan(r["mean"]):
                    value = f"{fmt(r['mean'])} ± {fmt(r['std'])}" if r["n_runs"] > 1 else fmt(r["mean"])
                    sort = repr(float(r["mean"]))
                for run_id, seed in zip(r["run_ids"], r["seeds"]):
                    cls = ' class="failed" title="failed"' if run_id in failed else ""
                    mark = "✗" if run_id in failed else ""
                    links.append(f'<a{cls} href="{h(run_href(run_id, "../"))}">s{seed}{mark}</a>')
            links += [f'<span class="missing" title="planned, no result">s{_int(s)}?</span>' for s in missing_seeds]
            cells.append(f'<td class="num" data-sort="{sort}">{h(value)}<div class="seeds">{"".join(links)}</div></td>')
        ref = (entry or {}).get("variants", {}).get(name) if entry else None
        for key in ("random_exact", "oracle_best", "oracle_worst"):
            cells.append(num_td(ref[key] if ref else None, classes="ref"))
        rows.append("<tr>" + "".join(cells) + "</tr>")
    return ('<div class="table-wrap"><table class="breakdown"><thead>' + head + "</thead><tbody>" + "".join(rows)
            + "</tbody></table></div>")


def _gif_gallery(sb: SiteBuild, group: Group, chain: str, scenario: str,
                 choices: dict[tuple[Group, str, str, str], dict[str, Any]]) -> str:
    items = []
    for learner in sb.lb.learners:
        record = choices.get((group, chain, scenario, learner))
        if record is None:
            continue
        src = "../" + sb.gifs[str(record["run_id"])]
        caption = (f'{dot(sb.colour(learner))}<strong>{h(learner)}</strong> · {h(record["variant"])} · seed '
                   f'{h(_int(record["seed"]))} · metric {h(fmt(record["metric"]))} · '
                   f'<a href="{h(run_href(str(record["run_id"]), "../"))}">run</a>')
        items.append(f'<figure><img src="{h(src)}" alt="{h("Evaluation episode of " + learner)}">'
                     f"<figcaption>{caption}</figcaption></figure>")
    if not items:
        return '<p class="note">No evaluation GIF was recorded for these runs.</p>'
    return '<div class="figs small">' + "".join(items) + "</div>"


def scenario_page(sb: SiteBuild, scenario: str, choices: dict[tuple[Group, str, str, str], dict[str, Any]]) -> str:
    spec, variant_names = _variant_specs(scenario)
    parts = [layout_section(sb, scenario, spec), variants_section(spec)]
    for group in sb.lb.groups:
        for chain, scen in sb.lb.pairs(group):
            if scen != scenario:
                continue
            radar = sb.figures.radars.get((group, chain, scenario))
            radar_html = (f'<figure><img src="../figures/{h(group.slug)}/{h(radar.name)}" '
                          f'alt="{h("Radar plot of " + chain + " in " + scenario)}"><figcaption>Per-norm morality '
                          'functions (relevant norms; mean over variants and seeds)</figcaption></figure>'
                          if radar is not None else '<p class="note">No per-norm data (no run with a result).</p>')
            parts.append(
                f'<section class="card" id="{h(section_id(group, chain))}">'
                f'<h2>{h(chain_title(chain))} <span class="muted small">· {h(group.label)}</span></h2>'
                f'<div class="row"><div>{_summary_table(sb, group, chain, scenario)}</div>{radar_html}</div>'
                '<h3>Per variant</h3><p class="note">Mean metric over seeds ± std over seeds; links to each seed\'s run '
                '(✗ failed, ? planned but missing). Reference columns: exact values for this variant.</p>'
                + _breakdown_table(sb, group, chain, scenario, variant_names)
                + "<h3>Evaluation episodes</h3>" + _gif_gallery(sb, group, chain, scenario, choices) + "</section>")
    summary = h(spec.summary) if spec is not None and spec.summary else ""
    crumbs = '<nav class="crumbs"><a href="../index.html">← Leaderboard</a></nav>'
    return page(scenario, "".join(parts), "../", summary, crumbs)


# ---------------------------------------------------------------------------------------- run pages
_METRICS = [
    ("metric", "Morality metric (final evaluation, Monte Carlo)", 4),
    ("metric_stderr", "Standard error of the metric", 4),
    ("exact_metric", "Exact metric of the final policy", 4),
    ("mean_return", "Mean return", 2),
    ("mean_cost", "Mean cost", 3),
    ("mean_length", "Mean episode length", 2),
    ("truncation_rate", "Truncation rate", 3),
    ("goal_rate", "Landmark reached rate", 3),
]
_INFO = [("budget", "Training budget (steps)"), ("total_steps", "Steps trained"), ("eval_episodes", "Evaluation episodes"),
         ("beta", "beta"), ("max_steps", "max_steps"), ("wall_time_s", "Wall time (s)"), ("started_at", "Started"),
         ("finished_at", "Finished"), ("hostname", "Host"), ("git_commit", "Git commit"), ("model_path", "Model"),
         ("gif_path", "GIF")]


def _pretty_json(text: Any) -> str:
    if text is None or (isinstance(text, float) and math.isnan(text)):
        return "(none)"
    try:
        return json.dumps(json.loads(str(text)), indent=2, sort_keys=True)
    except ValueError:
        return str(text)


def tracking_info(results_dir: Path, run_id: str) -> tuple[str, str | None]:
    """(``mlflow_run_id`` or a reason, ``experiment_id``) from ``<results>/tracking/<run_id>.json``."""
    path = results_dir / "tracking" / f"{safe_name(run_id)}.json"
    if not path.is_file():
        return "not synced", None
    try:
        body = json.loads(path.read_text())
        return str(body["mlflow_run_id"]), (str(body["experiment_id"]) if body.get("experiment_id") is not None else None)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"tracking file unreadable ({type(exc).__name__}: {exc})", None


def _value(record: dict[str, Any], key: str, digits: int | None = None) -> str:
    value = record.get(key)
    if value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value)):
        return "—"
    if digits is not None:
        return fmt(value, digits)
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def run_page(sb: SiteBuild, record: dict[str, Any]) -> str:
    from leaderboard.aggregate import chain_norm_order
    from runners.schema import MF_PREFIX

    root = "../"
    run_id = str(record["run_id"])
    status = "ok" if record["ok"] else "failed"
    group = Group(record["protocol"], record["preset"])
    head = (f'<section class="card"><h2><span class="badge {status}">{h(record["status"])}</span> '
            f'<span class="mono">{h(run_id)}</span></h2><dl class="kv">'
            f'<dt>Chain</dt><dd>{h(record["chain"])}</dd>'
            f'<dt>Scenario</dt><dd><a href="{h(scenario_href(str(record["scenario"]), root, section_id(group, str(record["chain"]))))}">'
            f'{h(record["scenario"])}</a></dd><dt>Variant</dt><dd>{h(record["variant"])} '
            f'(<span class="mono">{h(record["env_id"])}</span>)</dd>'
            f'<dt>Learner</dt><dd>{dot(sb.colour(str(record["learner"])))}{h(record["learner"])} '
            f'(<span class="mono">{h(record.get("algo"))}</span>)</dd>'
            f'<dt>Sweep</dt><dd>protocol {h(record["protocol"])}, preset {h(record["preset"])}</dd>'
            f'<dt>Seed</dt><dd>{h(_int(record["seed"]))}</dd></dl></section>')
    parts = [head]
    if not record["ok"]:
        error = record.get("error") or "(no error message)"
        parts.append(f'<section class="card" id="error"><h2 class="error">Error</h2><p class="error">{h(error)}</p>'
                     f'<h3>Traceback</h3><pre>{h(record.get("traceback") or "(no traceback recorded)")}</pre></section>')
    metrics = "".join(f"<dt>{h(label)}</dt><dd>{h(_value(record, key, digits))}</dd>" for key, label, digits in _METRICS)
    info = "".join(f"<dt>{h(label)}</dt><dd>{h(_value(record, key))}</dd>" for key, label in _INFO)
    mlflow_id, experiment = tracking_info(sb.results_dir, run_id)
    tracking = (f"<dt>MLflow run id</dt><dd class=\"mono\">{h(mlflow_id)}</dd>"
                + (f"<dt>MLflow experiment</dt><dd class=\"mono\">{h(experiment)}</dd>" if experiment else ""))
    parts.append(f'<section class="card" id="metrics"><h2>Metrics</h2><div class="row"><dl class="kv">{metrics}</dl>'
                 f'<dl class="kv">{info}{tracking}</dl></div></section>')
    relevant = set(record["relevant_norms"])
    norms = [n for n in chain_norm_order(str(record["chain"])) if f"{MF_PREFIX}{n}" in record]
    norms += sorted(k[len(MF_PREFIX):] for k in record if str(k).startswith(MF_PREFIX)
                    and k[len(MF_PREFIX):] not in norms and record[k] is not None and not _isnan(record[k]))
    rows = "".join(
        f'<tr><td>{i + 1}</td><td title="{h(norm_label(n))}">{h(norm_abbreviation(n))}</td><td class="mono">{h(n)}</td>'
        f'<td>{"relevant" if n in relevant else "<span class=muted>not relevant</span>"}</td>'
        + num_td(record.get(f"{MF_PREFIX}{n}"), 4) + "</tr>" for i, n in enumerate(norms))
    parts.append('<section class="card" id="norms"><h2>Morality functions per norm</h2><p class="note">In chain order '
                 '(highest force first). Only relevant norms carry weight in the metric.</p><table><thead><tr>'
                 '<th>#</th><th>Norm</th><th>Name</th><th>In this variant</th><th class="num">M</th></tr></thead>'
                 f"<tbody>{rows}</tbody></table></section>")
    media = []
    if run_id in sb.learn:
        media.append(f'<figure><img src="{root}{h(sb.learn[run_id])}" alt="Learning curve"><figcaption>Learn-time '
                     'evaluations</figcaption></figure>')
    if run_id in sb.gifs:
        media.append(f'<figure><img src="{root}{h(sb.gifs[run_id])}" alt="Evaluation episode"><figcaption>Evaluation '
                     'episode</figcaption></figure>')
    if media:
        parts.append('<section class="card" id="curves"><h2>Learning curve and episode</h2><div class="row">'
                     + "".join(media) + "</div></section>")
    elif run_id in sb.figures.learn_errors:
        parts.append('<section class="card" id="curves"><h2>Learning curve</h2><p class="error">The learn-time '
                     f'evaluations could not be drawn: {h(sb.figures.learn_errors[run_id])}</p></section>')
    else:
        parts.append('<section class="card" id="curves"><h2>Learning curve</h2><p class="note">No learn-time '
                     'evaluations recorded for this run.</p></section>')
    if run_id in sb.updates:
        parts.append('<section class="card" id="updates"><h2>What the learner did at each update</h2>'
                     '<p class="note">From <span class="mono">runs/&lt;run id&gt;.updates.parquet</span> (also in MLflow as '
                     '<span class="mono">update/*</span> metrics). See docs/protocols.md for the settings behind them.</p>'
                     f'<figure><img src="{root}{h(sb.updates[run_id])}" alt="Per-update diagnostics"></figure></section>')
    elif run_id in sb.figures.updates_errors:
        parts.append('<section class="card" id="updates"><h2>What the learner did at each update</h2><p class="error">'
                     f'The per-update diagnostics could not be drawn: {h(sb.figures.updates_errors[run_id])}</p></section>')
    parts.append(f'<section class="card" id="config"><h2>Configuration</h2><pre>{h(_pretty_json(record.get("config")))}</pre>'
                 f'<h3>Package versions</h3><pre>{h(_pretty_json(record.get("versions")))}</pre></section>')
    crumbs = (f'<nav class="crumbs"><a href="{root}index.html">← Leaderboard</a> · '
              f'<a href="{root}runs/index.html">All runs</a></nav>')
    title = f"{record['learner']} · {record['env_id']} · seed {_int(record['seed'])}"
    return page(title, "".join(parts), root, f"run <code>{h(run_id)}</code> · chain {h(record['chain'])}", crumbs)


def _isnan(value: Any) -> bool:
    return isinstance(value, float) and math.isnan(value)


# ---------------------------------------------------------------------------------------- build
def check_target(site_dir: Path) -> None:
    """Raise :class:`SiteError` unless ``site_dir`` is absent, empty, or a previous build of this module.

    Called before anything is built, so that a wrong ``--site`` costs nothing and deletes nothing.
    """
    if site_dir.exists():
        if not site_dir.is_dir():
            raise SiteError(f"{site_dir} exists and is not a directory")
        if any(site_dir.iterdir()) and not (site_dir / SITE_MARKER).is_file():
            raise SiteError(f"{site_dir} is not empty and was not built by leaderboard.site (no {SITE_MARKER}); "
                            "refusing to replace it: choose another --site or remove it yourself")


def _prepare_target(site_dir: Path) -> Path:
    """A fresh temporary directory next to ``site_dir``, where the new site is assembled."""
    check_target(site_dir)
    site_dir.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{site_dir.name}.build-", dir=site_dir.parent))


def _swap_in(tmp: Path, site_dir: Path) -> None:
    if site_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{site_dir.name}.old-", dir=site_dir.parent))
        old.rmdir()
        os.replace(site_dir, old)
        os.replace(tmp, site_dir)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, site_dir)


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def build_site(lb: Leaderboard, results_dir: Path, site_dir: Path, figures: FigureSet, results_name: str | None = None,
               progress: Progress | None = None) -> SiteBuild:
    """Write the whole site into ``site_dir`` (replacing a previous build); returns what was written."""
    tmp = _prepare_target(site_dir)
    try:
        sb = SiteBuild(lb=lb, results_dir=results_dir, results_name=results_name or str(results_dir),
                       figures=figures, out=tmp)
        (tmp / SITE_MARKER).write_text("built by leaderboard.site; this whole directory is replaced on every build\n")
        _write(tmp / "assets" / "site.css", CSS.lstrip())
        _write(tmp / "assets" / "site.js", JS.lstrip())
        copy_figures(sb)
        choices = gif_choices(lb, results_dir)
        copy_gifs(sb, choices)
        scenarios = sorted({s for _, s in lb.pairs()})
        render_layouts(sb, scenarios)
        _write(tmp / "index.html", index_page(sb))
        _write(tmp / "runs" / "index.html", runs_index_page(sb))
        for scenario in scenarios:
            _write(tmp / "scenarios" / f"{safe_name(scenario)}.html", scenario_page(sb, scenario, choices))
        records = lb.runs.to_dict("records")
        iterator: Iterable[Any] = progress(records, "run pages", len(records)) if progress and records else records
        for record in iterator:
            _write(tmp / "runs" / f"{safe_name(str(record['run_id']))}.html", run_page(sb, record))
        sb.pages = 2 + len(scenarios) + len(records)
        _swap_in(tmp, site_dir)
        sb.out = site_dir
        return sb
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
