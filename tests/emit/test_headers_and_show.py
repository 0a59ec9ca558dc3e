"""What a generated header and `derive show` tell about a model: the header of a model
built in Python says how it was generated (a Python call, since no command line names
that model), and `derive show` prints the inputs, B and D (or Fu and Qu), and each
sensor with its matrices."""

from __future__ import annotations

import sympy
from test_nav_sensors import TWO_SENSORS

from derive import LinearModel, cli, generate


def test_the_header_of_a_python_model_names_the_call_that_made_it(tmp_path):
    dt = sympy.Symbol("dt", positive=True)
    model = LinearModel("ctrv_like", ["s", "v"], ["z"], F=[[1, dt], [0, 1]], H=[[1, 0]],
                        Q=[[0.01, 0], [0, 0.01]], R=[[0.1]], parameters=["dt"])
    out = tmp_path / "out"
    generate(model, ["kf"], "python", out, options={"missing": True})
    text = (out / "ctrv_like" / "kf.py").read_text()
    assert ("Regenerate with:\n    derive.generate(model, 'kf', lang='python', "
            f"out={str(out)!r}, options={{'missing': True}}), model the LinearModel "
            "'ctrv_like' built in Python\n") in text
    assert "derive generate ctrv_like" not in text


def test_show_prints_inputs_B_D_and_the_sensors(tmp_path, capsys):
    path = tmp_path / "cart2.toml"
    path.write_text(TWO_SENSORS)
    assert cli.main(["show", str(path)]) == 0
    out = capsys.readouterr().out
    assert "inputs (u, one row per step): a, off" in out
    assert "\nB =\n" in out and "\nD =\n" in out
    assert "sensor gps: measurements zp; inputs off; update batch" in out
    assert "sensor speed: measurements zv; inputs none; update batch" in out
    assert "free parameters (p order): dt" in out
    for matrix in ("gps.H", "gps.D", "gps.R", "speed.H", "speed.R"):
        assert f"\n{matrix} =\n" in out
