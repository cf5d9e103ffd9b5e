"""Every recipe in examples/ runs (small inputs: the bundled sample log cut short, few lengths),
uses only the public API, and stays a short recipe."""
import ast
import runpy
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NAMES = ["identify_a_log", "close_the_loop", "design_and_bench", "sweep_and_export"]


def load(name):
    return runpy.run_path(str(EXAMPLES / f"{name}.py"), run_name="example")


@pytest.mark.parametrize("name", NAMES)
def test_example_is_a_short_public_recipe(name):
    src = (EXAMPLES / f"{name}.py").read_text()
    tree = ast.parse(src)
    assert ast.get_docstring(tree) and len(src.splitlines()) <= 60
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            assert not any(part.startswith("_") for part in node.module.split(".")), node.module
            assert not any(a.name.startswith("_") for a in node.names), node.module
        if isinstance(node, ast.Attribute):
            assert not node.attr.startswith("_"), node.attr
    assert "__import__" not in src


def test_identify_a_log(tmp_path, capsys):
    ident = load("identify_a_log")["main"](outdir=tmp_path, max_seeks=40)
    out = capsys.readouterr().out
    assert "k0 = " in out and "held-out fit" in out
    assert (tmp_path / "plant.json").exists() and (tmp_path / "fig5_tf.png").stat().st_size > 5000
    assert 3.5e9 < ident.plant.k0 < 4.4e9           # sample log truth: 3.94e9 track/(A s^2)


def test_close_the_loop(tmp_path, capsys):
    from seekopt.app.demo import sample_log_path
    truth = Path(sample_log_path()).with_suffix(".truth.json")
    res = load("close_the_loop")["main"](plant_path=str(truth), max_seeks=16)
    out = capsys.readouterr().out
    assert "validation RMS" in out and "fit % per seek" in out and "MATLAB" in out
    assert res.error_after["rms_track"] <= res.error_before["rms_track"] * (1 + 1e-9)


def test_design_and_bench(tmp_path, capsys):
    results = load("design_and_bench")["main"](outdir=tmp_path, lengths=(10, 100), robust=False)
    out = capsys.readouterr().out
    assert "optimal" in out and len(results) == 2
    for res in results:
        opt = res.row("optimal")
        assert opt.settled and opt.settle_time_s <= min(r.settle_time_s for r in res.rows if r.kind == "baseline")
    assert results[-1].figures and results[-1].figures[0].exists()


def test_sweep_and_export(tmp_path, capsys):
    summary, tables = load("sweep_and_export")["main"](outdir=tmp_path, tracks=(10,), designer="ocp")
    out = capsys.readouterr().out
    assert summary.ok and summary.total == 2 and len(tables.tables) == 2
    for n in ("seekopt_tables.h", "seekopt_tables.c", "seekopt_tables.csv", "seekopt_tables.json"):
        assert (tmp_path / "export" / n).exists(), n
    assert "saving_vs_best_pct" in out
