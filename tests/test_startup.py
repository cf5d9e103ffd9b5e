"""Start-up of ``seekopt design``: the design path does not import scipy.signal (issue 12: ~0.8 s of
CPU), and the controller realisation written for it equals scipy's entry for entry."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from seekopt.drive.sections import tf2ss

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("num,den", [
    ([1.0, -0.5], [1.0, -1.2, 0.5]),
    ([0.3, 0.1, -0.2], [2.0, -1.0, 0.3]),          # den not monic, proper with a direct term
    ([0.0, 0.0, 1.0], [1.0, 0.2, 0.1]),            # leading numerator zeros
    ([0.2], [1.0, -0.9]),
    ([1.0, 2.0, 3.0, 4.0], [1.0, -0.1, 0.2, -0.05]),
    ([0.0, 1e-15, 0.5], [0.0, 1.0, -0.3, 0.02]),   # leading zeros in both
])
def test_tf2ss_equals_scipy(num, den):
    A, B, C, D = tf2ss(num, den)
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            As, Bs, Cs, Ds = signal.tf2ss(num, den)
    assert A.shape == As.shape and np.array_equal(A, As)
    assert np.array_equal(B, Bs.ravel()) and np.array_equal(C, Cs.ravel())
    assert D == float(Ds.ravel()[0])


def test_tf2ss_rejects_improper():
    with pytest.raises(ValueError):
        tf2ss([1.0, 2.0, 3.0], [1.0, 0.5])


def test_design_path_imports_no_scipy_signal(tmp_path):
    """Building a nominal designer and designing one seek in a fresh process leaves scipy.signal
    (and scipy.stats, which it pulls in) unimported."""
    code = (
        "import sys, json\n"
        "from seekopt.design.designer import SeekDesigner\n"
        "from seekopt.drive.controller import Controller\n"
        "from seekopt.drive.presets import default_truth_plant\n"
        "d = SeekDesigner(default_truth_plant(), Controller.nss(), 0.3)\n"
        "d.design(50.0)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('scipy.signal') or m.startswith('scipy.stats'))))\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []


def _fresh(code: str, tmp_path, **env_extra):
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                            "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")}
    env.update(PYTHONPATH=str(ROOT), **env_extra)
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_cli_blas_limit_before_numpy_loads(tmp_path):
    """The command line's BLAS limit in a fresh process: no library loaded yet, so the environment alone
    limits numpy's and scipy's OpenBLAS when they load (one thread each, nothing imported early); with
    numpy already loaded, threadpoolctl limits it."""
    code = ("import sys, json\n"
            "from seekopt.app import cli\n"
            "early = 'numpy' in sys.modules\n"
            "with cli._blas_threads():\n"
            "    before = sorted(m for m in ('numpy', 'scipy', 'threadpoolctl') if m in sys.modules)\n"
            "    import numpy, scipy.linalg\n"
            "    from threadpoolctl import threadpool_info\n"
            "    n = sorted({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'})\n"
            "print(json.dumps([early, before, n]))\n")
    assert _fresh(code, tmp_path) == [False, [], [1]]
    code2 = ("import sys, json, numpy, scipy.linalg\n"
             "from seekopt.app import cli\n"
             "from threadpoolctl import threadpool_info\n"
             "with cli._blas_threads():\n"
             "    n = sorted({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'})\n"
             "print(json.dumps(n))\n")
    assert _fresh(code2, tmp_path, OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="2") == [1]


def test_cli_robust_design_imports_no_scipy_optimize(tmp_path):
    """``seekopt design --robust`` K = 1000 on the bundled plant (the cold-start benchmark of issue 12)
    proves its infeasible lengths without scipy.optimize (0.15 s of import) or scipy.signal."""
    plant = ROOT / "seekopt" / "data" / "sample_log.truth.json"
    code = ("import sys, json\n"
            "from seekopt.app.cli import main\n"
            f"rc = main(['design', '--plant', {str(plant)!r}, '--tracks', '1000', '--imax', '0.3', '--robust',"
            " '-q', '-o', 'p.csv'])\n"
            "print(json.dumps([rc, sorted(m for m in sys.modules if m.startswith(('scipy.optimize', 'scipy.signal')))]))\n")
    assert _fresh(code, tmp_path, OPENBLAS_NUM_THREADS="1") == [0, []]
