"""tendon2r-identify's HTML report: it opens offline, and each figure means something in its
unit (tendon2r_gym.identification.report)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tendon2r_gym.app.excitation import MultiSine, record
from tendon2r_gym.envs.env_config import EnvConfig
from tendon2r_gym.identification.identify import identify
from tendon2r_gym.identification.report import (
    NOT_APPLICABLE,
    ParameterRow,
    parameter_rows,
    save_html,
    summary_rows,
)

pytest.importorskip("mujoco.sysid.report")

#: A network source in the page: an attribute or a style sheet's url() or @import.
NETWORK = re.compile(r"""(?:\b(?:src|href)\s*=\s*["']?|url\(\s*["']?)\s*https?://""", re.I)
#: A style sheet's import of another (from anywhere: the page is whole without it).
IMPORT = re.compile(r"@import\b", re.I)
SCRIPT = re.compile(r"(<script\b[^>]*>)(.*?)(</script>)", re.I | re.S)


@pytest.fixture(scope="module")
def ident():
    # Two fields: the mass scale (nominal 1) and the extra joint damping (nominal 0), on the
    # shortest recording that gives them pieces enough.
    arm = EnvConfig.make("default")
    signal = MultiSine(amp_rad=(0.1, 0.08), bias_rad=(0.1, -0.2))
    rec = record(arm, "pd", 1.7, seed=0, signal=signal)
    return identify([rec], arm, ["density_scale", "extra_joint_damping"], threads=1)


@pytest.fixture(scope="module")
def page(ident, tmp_path_factory) -> str:
    path = save_html(ident, tmp_path_factory.mktemp("report") / "arm.html")
    return path.read_text(encoding="utf-8")


def test_the_report_loads_nothing_from_the_network(page):
    from plotly.offline import get_plotlyjs

    # Script bodies are code (the inlined plotly's own strings name its website): what the
    # page loads is in its tags' attributes and its style sheets.
    tags = [m.group(1) for m in SCRIPT.finditer(page)]
    markup = SCRIPT.sub(lambda m: m.group(1) + m.group(3), page)
    assert tags and not any(re.search(r"\bsrc\s*=", tag, re.I) for tag in tags), tags
    assert not NETWORK.findall(markup), NETWORK.findall(markup)
    assert not IMPORT.findall(markup), IMPORT.findall(markup)
    assert get_plotlyjs() in page  # the plotting library, inlined once
    assert page.count(get_plotlyjs()[:200]) == 1


def test_a_zero_nominal_field_has_no_relative_change(ident, page):
    rows = {r.field: r for r in parameter_rows(ident)}
    damping, mass = rows["extra_joint_damping"], rows["density_scale"]
    assert damping.nominal == 0.0 and damping.relative_change is None
    assert damping.cells()[7] == NOT_APPLICABLE
    assert mass.relative_change == pytest.approx(mass.fitted - 1.0)
    assert mass.cells()[7].endswith("%")
    assert page.count(NOT_APPLICABLE) == 1  # the damping's row alone


def test_each_row_holds_its_field_in_its_unit(ident):
    for row, e in zip(parameter_rows(ident), ident.estimates, strict=True):
        assert (row.field, row.unit, row.nominal, row.fitted) == (
            e.field,
            e.unit,
            e.nominal,
            e.value,
        )
        assert row.interval == e.interval and row.change == e.value - e.nominal
        assert row.bounds[0] <= row.fitted <= row.bounds[1]
    found = dict(summary_rows(ident))
    assert found["loop delay (motor + sensor)"].startswith(f"{ident.loop_delay_s * 1e3:g} ms")
    assert found["sensor noise, angles"].endswith(" rad")


@pytest.mark.parametrize(
    "nominal, fitted, relative",
    [(0.0, 3e-6, None), (2.0, 3.0, 0.5), (-2.0, -3.0, -0.5), (1.0, 1.0, 0.0)],
)
def test_the_relative_change_is_against_the_nominal_magnitude(nominal, fitted, relative):
    row = ParameterRow("f", "N", nominal, fitted, (fitted, fitted), (-10.0, 10.0), "identified")
    assert row.relative_change == relative
    if relative is None:
        assert row.cells()[7] == NOT_APPLICABLE
    else:
        assert float(row.cells()[7].rstrip("%")) == pytest.approx(100 * relative)
    assert np.isfinite(row.change)
