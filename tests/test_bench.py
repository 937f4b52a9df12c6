"""`stw bench` prints a row per configuration with same-run ratios (no timing assertions)."""

import argparse
import re

from conftest import SESSIONS
from stw_tui import bench


def test_bench_table_has_a_row_per_configuration(capsys, monkeypatch):
    monkeypatch.setattr(bench, "synthetic_session", lambda dofs, knots: "")   # keep it short
    bench.run_bench(argparse.Namespace(sessions=[SESSIONS / "particle_jet.stw"], repeat=1))
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("particle_jet ")]
    configs = {" ".join(c).strip() for c in bench.configurations()}
    assert len(rows) == len(configs)
    reference = next(r for r in rows if "solver=direct" in r)
    numbers = re.findall(r"[-+]?\d+\.?\d*(?:e[-+]\d+)?", reference.split("direct", 1)[1])
    free, instances, iterations = (int(float(x)) for x in numbers[:3])
    assert (free, instances, iterations) == (15, 4, 1)
    assert " 1.00 " in reference                       # the reference's own ratio
    assert "108.236" in reference                      # the particle's optimum, 12 + g^2
