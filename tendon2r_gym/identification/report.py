"""What identification writes: the identified arm's experiment file, and the toolbox's HTML
report (``mujoco.sysid.report``) of predicted against measured motion."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import yaml

from tendon2r_gym.identification.result import Identification


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


def _params(ident: Identification, which: str):
    from mujoco import sysid

    out = sysid.ParameterDict()
    prob = ident.extras["problem"]
    for e in ident.estimates:
        lo, hi, _ = prob.box[e.field]
        out.add(sysid.Parameter(e.field, e.nominal, lo, hi))
        out[e.field].value[:] = e.value if which == "fit" else e.nominal
    return out


def save_html(ident: Identification, path: str | os.PathLike) -> Path:
    """Writes the toolbox's report: the parameters (nominal and fitted: a flagged field's
    fitted value too, for diagnosis), their 95% intervals and correlations, and each joint's
    angle over the pieces as measured, replayed on the nominal arm and on the fitted one."""
    from mujoco.sysid import TimeSeries
    from mujoco.sysid.report.builder import ReportBuilder
    from mujoco.sysid.report.sections.covariance import Covariance
    from mujoco.sysid.report.sections.parameter_distribution import ParameterDistribution
    from mujoco.sysid.report.sections.parameters import ParametersTable
    from mujoco.sysid.report.sections.signals import SignalReport

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    prob = ident.extras["problem"]
    rep = prob.rep
    x = ident.extras["x"]
    fitted, nominal = _params(ident, "fit"), _params(ident, "nominal")
    rb = ReportBuilder("tendon2r-identify: " + ", ".join(ident.sources))
    if ident.estimates:
        rb.add_section(ParametersTable("Parameters", fitted, nominal, anchor="parameters"))
        half = np.array([e.half_width for e in ident.estimates])
        rb.add_section(
            ParameterDistribution(
                title="Parameter distribution (95% simultaneous intervals, cluster-robust)",
                opt_params=fitted,
                initial_params=nominal,
                confidence_intervals=half,
                anchor="distribution",
            )
        )
        scales = prob.scales
        rb.add_section(
            Covariance(
                title="Covariance and correlation",
                anchor="covariance",
                covariance=ident.extras["cov"] * np.outer(scales, scales),
                parameter_dict=fitted,
            )
        )
    # The pieces' angles back to back: measured, replayed on the nominal and identified arms.
    measured = rep._measured.reshape(-1, 2)
    fit_q = rep.angles([prob.arm(x)])[0].reshape(-1, 2)
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
    rb.add_section(
        SignalReport(
            "Joint angles (rad) over the pieces, each replayed from its start",
            None,
            ts_dict=series,
            max_datapoints=None,
        )
    )
    rb.build()
    rb.save(str(path))
    return path
