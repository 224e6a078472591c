"""README.md's "Output files" section against what the code writes: every history.csv column, summary.json key
and particle kind that tiny runs of a few scenes produce must be listed in the section's tables, so that the
reference cannot go stale unnoticed."""

import json
import re

import pytest

from psph.particles import Kind
from tests.helpers import CASES, ROOT

README = ROOT / "README.md"

# tiny runs that between them write every family of history columns and summary keys: static, kinematic and
# flow runs; IIPS with NFTS and with MLS; probes; clone walls, gravity, a free surface, the dam break's
# diagnostics; open boundaries (a non-reflecting inflow), an immersed body, the jet's diagnostics; packing
# and the drop's reference
RUNS = {
    "static": ("static_perturbed", "domain.dx=0.1", "shifting.method=iips", "iips.max_newton=2"),
    "kinematic": ("kinematic_tgv", "domain.dx=0.1", "time.t_end=0.02", "iips.pre_newton=2"),
    "taylor_green": ("taylor_green", "domain.dx=0.1", "time.t_end=0.02", "iips.update=nfts",
                     "output.probes=[[0.5,0.5]]"),
    "dam_break": ("dam_break", "domain.dx=0.2", "time.t_end=0.05", "shifting.method=iips", "iips.update=mls2"),
    "jet": ("impinging_jet", "domain.dx=0.2", "domain.upper=[4.0,7.0]", "inflow.0.upper=[1.0,6.8]",
            "time.t_end=0.05", "inflow.0.density=extrapolated", "inflow.0.non_reflecting_time=1.0"),
    "drop": ("elliptical_drop", "domain.dx=0.1", "time.t_end=0.02", "packing.iterations=5",
             "shifting.method=iips", "iips.update=mls2"),
}


def output_tables():
    """The tables of the README's Output files section: a list of (caption, rows), the caption being the
    paragraph before the table and each row a list of its cells (escaped pipes kept)."""
    text = README.read_text()
    start = text.index("\n### Output files\n")
    section = text[start + 1: text.index("\n## ", start)]
    tables, caption, rows = [], "", None
    for line in section.splitlines():
        if line.startswith("|"):
            if rows is None:
                rows = []
                tables.append((caption, rows))
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
            if not set("".join(cells)) <= set("-: "):
                rows.append(cells)
        else:
            if rows is not None:
                rows, caption = None, ""
            if line.strip():
                caption += " " + line.strip()
    return tables


def documented(keyword):
    """(names, patterns) listed in the first column of the tables whose caption contains `keyword` (the
    header rows left out): backticked names, NAME standing for any name; a row that says its names are
    "suffixed `_NAME`" also lists them with a suffix."""
    names, patterns = set(), []
    for caption, rows in output_tables():
        if keyword not in caption:
            continue
        for cells in rows[1:]:
            for name in re.findall(r"`([^`]+)`", cells[0]):
                if "NAME" in name:
                    patterns.append(re.compile(re.escape(name).replace("NAME", r"[\w.-]+") + "$"))
                else:
                    names.add(name)
                    if "suffixed `_NAME`" in " ".join(cells[1:]):
                        patterns.append(re.compile(re.escape(name) + r"_[\w.-]+$"))
    assert names, f"README's Output files section has no table captioned with {keyword!r}"
    return names, patterns


def undocumented(found, keyword):
    names, patterns = documented(keyword)
    return sorted(k for k in found if k not in names and not any(p.match(k) for p in patterns))


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """{run: (history header, summary.json)} of the tiny runs, in this process (the kernels compiled once)."""
    from psph.cli import main

    base = tmp_path_factory.mktemp("docs")
    result = {}
    for name, (scene, *sets) in RUNS.items():
        out = base / name
        args = ["run", str(CASES / f"{scene}.toml"), "--out", str(out), "--quiet"]
        for s in sets:
            args += ["--set", s]
        assert main(args) == 0, name
        header = (out / "history.csv").read_text().splitlines()[0].split(",")
        result[name] = (header, json.loads((out / "summary.json").read_text()))
    return result


def test_every_history_column_is_in_the_readme(outputs):
    columns = {c for header, _ in outputs.values() for c in header}
    missing = undocumented(columns, "history.csv")
    assert not missing, f"history.csv columns missing from README's Output files tables: {missing}"


def test_every_summary_key_is_in_the_readme(outputs):
    keys = {k for _, summary in outputs.values() for k in summary}
    missing = undocumented(keys, "summary.json")
    assert not missing, f"summary.json keys missing from README's Output files tables: {missing}"


def test_every_particle_kind_is_in_the_readme():
    rows = next(rows for caption, rows in output_tables() if "`kind` codes" in caption)
    listed = {(cells[0], cells[1].strip("`")) for cells in rows[1:]}
    missing = sorted({(str(int(k)), k.name) for k in Kind} - listed)
    assert not missing, f"particle kinds (code, name) missing from README's kind table: {missing}"


def test_the_check_fails_on_a_missing_row():
    """The checks can fail: a column, key or kind no table lists is reported."""
    assert undocumented({"time", "no_such_column"}, "history.csv") == ["no_such_column"]
    assert undocumented({"force_x_tank", "cd_pressure_plate"}, "history.csv") == []
    assert undocumented({"final", "no_such_key"}, "summary.json") == ["no_such_key"]
