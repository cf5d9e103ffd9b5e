"""The README's "Python API" snippets run as written (in order, in one namespace), from a folder
holding a ``plant.json`` as ``seekopt identify`` writes it."""
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def api_snippets() -> list[str]:
    text = README.read_text()
    m = re.search(r"^## Python API\n(.*?)(?=^## )", text, flags=re.S | re.M)
    assert m, "README has no 'Python API' section"
    return re.findall(r"^```python\n(.*?)^```", m.group(1), flags=re.S | re.M)


def test_readme_has_the_api_snippets():
    code = "\n".join(api_snippets())
    for what in ("ModalPlant.load(", ".to_control()", "SeekDesigner(", "for tracks in", "run_sweep("):
        assert what in code


def test_readme_python_api_snippets_run(tmp_path, monkeypatch, capsys):
    from seekopt.app.demo import sample_log_path
    from identification.model.plant import ModalPlant
    truth = ModalPlant.load(Path(sample_log_path()).with_suffix(".truth.json"))
    truth.to_json(tmp_path / "plant.json")
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__readme__"}
    for i, code in enumerate(api_snippets()):
        exec(compile(code, f"README.md Python API snippet {i + 1}", "exec"), namespace)
    out = capsys.readouterr().out
    a, b = re.search(r"= ([\d.e+-]+) track/A \(ModalPlant.frf: ([\d.e+-]+)\)", out).groups()
    assert float(a) == pytest.approx(float(b), rel=1e-9)
    assert {p.name for p in tmp_path.glob("k*.csv")} == {"k10.csv", "k200.csv", "k1000.csv"}
    assert "4 cells computed, all ok: True" in out
    assert (tmp_path / "sweep-out" / "results.csv").exists()
