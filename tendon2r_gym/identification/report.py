"""What identification writes: the identified arm's experiment file, and its HTML report.

The report is built with the toolbox's report builder (``mujoco.sysid.report``): its charts of
the parameters and their correlations, and of the measured angles against their replay.  Its
parameter table is our own: each field's change in the field's unit, and a relative change
only where the nominal value is not 0 (the toolbox's table divides by it, and sums every
field's change into one RMSE of mixed units).  The page is self-contained: plotly inlined,
no web fonts, nothing loaded from the network, so that it opens offline.
"""

from __future__ import annotations

import html
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tendon2r_gym.identification.fit import PIECE_S
from tendon2r_gym.identification.result import Estimate, Identification

#: The relative change of a field whose nominal value is 0.
NOT_APPLICABLE = "n/a (nominal 0)"
#: What the page would load from the network: plotly's script from its CDN (or any other
#: script), a web font's stylesheet (``@import url(...)`` or ``<link href=...>``).
_PLOTLY_CDN = re.compile(
    r"""<script\b[^>]*\bsrc\s*=\s*["']?https?://cdn\.plot\.ly/[^>]*>\s*</script>"""
)
_CDN_SCRIPT = re.compile(r"""<script\b[^>]*\bsrc\s*=\s*["']?https?://[^>]*>\s*</script>""", re.I)
_WEB_IMPORT = re.compile(r"""@import\s+url\(\s*["']?https?://[^)]*\)\s*;?""", re.I)
_WEB_LINK = re.compile(r"""<link\b[^>]*\bhref\s*=\s*["']?https?://[^>]*>""", re.I)


def save_experiment(ident: Identification, path: str | os.PathLike, nominal: str) -> Path:
    """Writes the identified arm's experiment file (every command takes it as it is), with
    the identification's table as its header comment."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    head = [
        f"Identified by tendon2r-identify from {', '.join(ident.sources)} on the nominal arm "
        f"{nominal}.",
        "Fields not identified keep their nominal values, unless the recording rules them out.",
        *ident.lines(),
    ]
    text = "".join(f"# {line}\n" for line in head)
    text += yaml.safe_dump(ident.experiment(nominal), sort_keys=False, default_flow_style=None)
    path.write_text(text)
    return path


@dataclass(frozen=True)
class ParameterRow:
    """One field of the report's parameter table, in the field's unit."""

    field: str
    unit: str
    nominal: float
    fitted: float  # a flagged field's too, for diagnosis
    interval: tuple[float, float]  # 95%, simultaneous
    bounds: tuple[float, float]  # of the fit
    status: str  # identified, or why not and what the identified arm takes

    @property
    def change(self) -> float:
        """Fitted minus nominal (the field's unit)."""
        return self.fitted - self.nominal

    @property
    def relative_change(self) -> float | None:
        """The change as a fraction of the nominal value; None where that is 0."""
        return None if self.nominal == 0 else self.change / abs(self.nominal)

    def cells(self) -> list[str]:
        """The table's cells: numbers to 4 significant digits, the relative change in %."""
        rel = self.relative_change
        return [
            self.field,
            self.unit,
            f"{self.nominal:.4g}",
            f"{self.fitted:.4g}",
            f"[{self.interval[0]:.4g}, {self.interval[1]:.4g}]",
            f"[{self.bounds[0]:.4g}, {self.bounds[1]:.4g}]",
            f"{self.change:+.4g}",
            NOT_APPLICABLE if rel is None else f"{rel:+.1%}",
            self.status,
        ]


def _status(e: Estimate) -> str:
    """Whether the field is identified, and if not why and what the identified arm takes."""
    if e.identified:
        return "identified"
    if e.used:
        return f"not identifiable ({e.why}); the interval excludes the nominal value: taken"
    return f"not identifiable ({e.why}); nominal kept"


def parameter_rows(ident: Identification) -> list[ParameterRow]:
    """The report's parameter table: one row per fitted field."""
    box = ident.extras["problem"].box
    return [
        ParameterRow(e.field, e.unit, e.nominal, e.value, e.interval, box[e.field][:2], _status(e))
        for e in ident.estimates
    ]


def summary_rows(ident: Identification) -> list[tuple[str, str]]:
    """The report's other findings, each with its unit: the loop delay, the sensors' noise,
    the angle residual and the fields skipped."""
    angle, speed = ident.noise
    before, after = ident.residual_rms_rad
    rows = [
        (
            "loop delay (motor + sensor)",
            f"{ident.loop_delay_s * 1e3:g} ms ({_delay_status(ident)})",
        ),
        ("sensor noise, angles", f"{angle:.3g} rad"),
        ("sensor noise, speeds", "not recorded" if speed is None else f"{speed:.3g} rad/s"),
        ("angle residual RMS", f"{before:.3g} rad before the fit, {after:.3g} rad after"),
        ("pieces", f"{ident.pieces} of {PIECE_S} s"),
    ]
    return rows + [(f"{name} (skipped)", why) for name, why in ident.skipped.items()]


def _delay_status(ident: Identification) -> str:
    """Whether the loop delay is identified, or the delays not told apart from it."""
    lo, hi = (v * 1e3 for v in ident.delay_range_s)
    if ident.delay_identified:
        return "identified"
    if lo == hi:
        return "not identified"
    return f"not told from {lo:g}-{hi:g} ms"


_TABLE_STYLE = """<style>
table.t2r { border-collapse: collapse; font-size: 0.9rem; color: var(--text-color); }
table.t2r th, table.t2r td { padding: 6px 10px; border: 1px solid var(--border-color); }
table.t2r th { background-color: var(--bg-color); text-align: left; }
table.t2r td.num { text-align: right; white-space: nowrap; }
</style>"""


def _table(header: list[str], rows: list[list[str]], text_columns: set[int]) -> str:
    """An HTML table of escaped text; the columns not in ``text_columns`` right-aligned."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(_cell(c, i not in text_columns) for i, c in enumerate(row)) + "</tr>"
        for row in rows
    )
    table = f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody>"
    return f'{_TABLE_STYLE}<table class="t2r">{table}</table>'


def _cell(text: str, numeric: bool) -> str:
    """One table cell of escaped ``text`` (a number right-aligned)."""
    return (
        f'<td class="num">{html.escape(text)}</td>' if numeric else f"<td>{html.escape(text)}</td>"
    )


def _section(title: str, anchor: str, body: str, caption: str = "") -> Any:
    """A report section of our own HTML ``body`` (the toolbox's generic template)."""
    from mujoco.sysid.report.sections.base import ReportSection

    class Section(ReportSection):
        template_filename = "plot_generic.html"

        @property
        def title(self) -> str:
            return title

        @property
        def anchor(self) -> str:
            return anchor

        def get_context(self) -> dict[str, Any]:
            return {"title": title, "plot_div": body, "caption": caption}

    return Section()


def _label(e: Estimate) -> str:
    """A field's name with its unit, for the toolbox's charts."""
    return e.field if e.unit == "1" else f"{e.field} ({e.unit})"


def _params(ident: Identification, which: str) -> Any:
    """The fields as the toolbox's parameters, at their fitted or nominal values."""
    from mujoco import sysid

    out = sysid.ParameterDict()
    prob = ident.extras["problem"]
    for e in ident.estimates:
        lo, hi, _ = prob.box[e.field]
        out.add(sysid.Parameter(_label(e), e.nominal, lo, hi))
        out[_label(e)].value[:] = e.value if which == "fit" else e.nominal
    return out


def _parameter_sections(ident: Identification) -> list[Any]:
    """The fields' table, the other findings, and the toolbox's charts of the fields' values
    and intervals and of their covariance and correlation."""
    from mujoco.sysid.report.sections.covariance import Covariance
    from mujoco.sysid.report.sections.parameter_distribution import ParameterDistribution

    header = ["field", "unit", "nominal", "fitted", "95% interval", "bounds", "change"]
    header += ["relative change", "status"]
    rows = [r.cells() for r in parameter_rows(ident)]
    found = _table(["finding", "value"], [list(r) for r in summary_rows(ident)], {0, 1})
    sections = [_section("Findings", "findings", found)]
    if not ident.estimates:
        return sections
    caption = "Each field in its own unit; the relative change is against a nonzero nominal value."
    table = _section("Parameters", "parameters", _table(header, rows, {0, 1, 8}), caption)
    fitted, nominal = _params(ident, "fit"), _params(ident, "nominal")
    half = np.array([e.half_width for e in ident.estimates])
    scales = ident.extras["problem"].scales
    return [
        table,
        *sections,
        ParameterDistribution(
            title="Parameter distribution (95% simultaneous intervals, cluster-robust)",
            opt_params=fitted,
            initial_params=nominal,
            confidence_intervals=half,
            anchor="distribution",
        ),
        Covariance(
            title="Covariance and correlation",
            anchor="covariance",
            covariance=ident.extras["cov"] * np.outer(scales, scales),
            parameter_dict=fitted,
        ),
    ]


def _angles_section(ident: Identification) -> Any:
    """The pieces' angles back to back: measured, replayed on the nominal and identified arms."""
    from mujoco.sysid import TimeSeries
    from mujoco.sysid.report.sections.signals import SignalReport

    prob = ident.extras["problem"]
    rep = prob.rep
    measured = rep._measured.reshape(-1, 2)
    fit_q = rep.angles([prob.arm(ident.extras["x"])])[0].reshape(-1, 2)
    nom_q = rep.angles([prob.arm(prob.x0)])[0].reshape(-1, 2)
    # One time axis: each recording after the last one's end (their clocks may restart).
    offsets = np.cumsum([0.0] + [r.time[-1] - r.time[0] + 1.0 for r in prob.recordings])
    t = np.concatenate(
        [
            prob.recordings[i].time[s + 1 : s + 1 + rep.pieces.length]
            - prob.recordings[i].time[0]
            + offsets[i]
            for i, s in rep.pieces.starts
        ]
    )
    mapping = {"q_A": ("q_A", [0]), "q_B": ("q_B", [1])}
    series = {
        "measured": TimeSeries(t, measured, mapping),
        "nominal": TimeSeries(t, nom_q, mapping),
        "identified": TimeSeries(t, fit_q, mapping),
    }
    return SignalReport(
        "Joint angles (rad) over the pieces, each replayed from its start",
        None,
        ts_dict=series,
        max_datapoints=None,
    )


def self_contained(page: str) -> str:
    """Returns the page with plotly's script inlined in place of its CDN's, and without web
    fonts (the page's own font lists fall back to the system's)."""
    from plotly.offline import get_plotlyjs

    script = f'<script type="text/javascript">{get_plotlyjs()}</script>'
    page = _PLOTLY_CDN.sub(lambda _: script, page, count=1)
    for pattern in (_CDN_SCRIPT, _WEB_IMPORT, _WEB_LINK):
        page = pattern.sub("", page)
    return page


def save_html(ident: Identification, path: str | os.PathLike) -> Path:
    """Writes the report: the fields (nominal and fitted: a flagged field's fitted value too,
    for diagnosis) with their 95% intervals and correlations, the other findings, and each
    joint's angle over the pieces as measured, replayed on the nominal arm and on the fitted
    one.  It opens offline (self_contained)."""
    from mujoco.sysid.report.builder import ReportBuilder

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rb = ReportBuilder("tendon2r-identify: " + ", ".join(ident.sources))
    for section in [*_parameter_sections(ident), _angles_section(ident)]:
        rb.add_section(section)
    path.write_text(self_contained(rb.build()), encoding="utf-8")
    return path
