"""The mjkin command: output, and user mistakes as one line with exit status 2."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import mjkin
from mjkin.cli import main


def test_info_outlines_the_tree(capsys):
    assert main(["info", "primate"]) == 0
    out = capsys.readouterr().out
    assert "nq=37 nv=30" in out
    assert "joint root: free" in out and "joint left_knee: hinge" in out and "site head" in out


def test_fk_json_equals_library(capsys):
    q = "0.1 0.2 0.3 -0.4 0.5 0.6 0.7"
    assert main(["fk", "arm7", "--q", q, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    tree = mjkin.load("arm7")
    T = tree.pose([float(v) for v in q.split()], "ee")
    ee = next(f for f in data["frames"] if f["name"] == "ee")
    np.testing.assert_allclose(ee["pos"], T[:3, 3], atol=1e-12)


def test_fk_degrees(capsys):
    assert main(["fk", "planar_2link", "--q", "90,0", "--deg", "--frame", "tip"]) == 0
    assert "pos  0.000000  1.700000  0.000000" in capsys.readouterr().out


@pytest.mark.parametrize("argv, text", [
    (["fk", "arm7", "--q", "1 2"], "needs (..., 7)"),
    (["fk", "arm7", "--q", "1 2 x 4 5 6 7"], "--q must be 7 numbers"),
    (["fk", "arm7", "--frame", "hand"], "unknown site or body 'hand'"),
    (["info", "no_such_model"], "model file not found"),
    (["fk", "arm7", "--q", "0 0 0 nan 0 0 0"], "NaN"),
])
def test_user_mistakes_exit_2_with_one_line(argv, text, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert text in err and err.count("\n") == 1 and "Traceback" not in err


def test_console_script_exits_2_without_traceback(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body>")
    r = subprocess.run([sys.executable, "-m", "mjkin.cli", "info", str(bad)], capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.startswith("mjkin: error: cannot compile model") and "Traceback" not in r.stderr
