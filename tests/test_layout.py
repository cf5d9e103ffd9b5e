"""The tree follows the pipeline: no module imports a stage to its right (docs/ARCHITECTURE.md)."""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: pipeline order; a module may import its own stage and stages with a lower rank
STAGES = ["identification.fileio", "identification.model", "identification.logs", "identification.estimate",
          "identification.loop", "seekopt.drive", "seekopt.design", "seekopt.evaluate", "seekopt.export",
          "seekopt.app"]


def _stage(module: str) -> int | None:
    for i, s in enumerate(STAGES):
        if module == s or module.startswith(s + "."):
            return i
    return None


def _modules():
    for pkg in ("identification", "seekopt"):
        for f in sorted((ROOT / pkg).rglob("*.py")):
            yield ".".join(f.relative_to(ROOT).with_suffix("").parts), f


def _imports(path: Path, module: str):
    tree = ast.parse(path.read_text())
    package = module.rsplit(".", 1)[0] if path.name != "__init__.py" else module
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                yield ".".join(base + ([node.module] if node.module else []))
            elif node.module:
                yield node.module
                for a in node.names:  # "from seekopt import app" names a sub-package
                    yield f"{node.module}.{a.name}"


@pytest.mark.parametrize("module,path", list(_modules()), ids=lambda x: str(x) if isinstance(x, str) else "")
def test_no_import_runs_up_the_pipeline(module, path):
    own = _stage(module)
    if own is None:
        return  # package roots (version only)
    up = sorted({m for m in _imports(path, module) if (_stage(m) or -1) > own})
    assert not up, f"{module} imports {up}, which lie to its right in the pipeline {STAGES}"
