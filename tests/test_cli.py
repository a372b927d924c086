"""The `jaxworm simulate` command line, called in-process (`main([...])`).

Two solves in all, to keep this file short: a summary run (t1 = 0.5 s) and a dense run
with a figure (t1 = 0.2 s, omega = 3*pi). Usage errors never reach a solve.
"""

import json
import math

import pytest

import jaxworm as jw
from jaxworm._cli import main, parse_value

SUMMARY_KEYS = {
    "mean_velocity": float, "n_cracks": int, "crack_times": list, "final_head": float,
    "final_crack_tip": float, "status": str, "steps": int, "wall_time_s": float,
    "energy_residual": float, "parameters": dict,
}


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    """A private persistent-compilation-cache folder for this module's runs."""
    path = tmp_path_factory.mktemp("jax_cache")
    mp = pytest.MonkeyPatch()
    mp.setenv("JAXWORM_CACHE_DIR", str(path))
    yield path
    mp.undo()


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def json_run(cache_dir):
    import io
    from contextlib import redirect_stdout

    import jax

    # Another test may have compiled the same program in this process; then the run
    # would hit JAX's in-memory cache and write nothing to the persistent one.
    jax.clear_caches()
    buf = io.StringIO()
    with redirect_stdout(buf):
        code = main(["simulate", "--set", "t1=0.5", "--json"])
    return code, buf.getvalue()


def test_json_output_is_one_object_with_typed_keys_and_status_ok(json_run):
    code, out = json_run
    assert out.count("\n") == 1, "stdout must hold exactly one JSON line"
    report = json.loads(out)
    for key, kind in SUMMARY_KEYS.items():
        assert isinstance(report[key], kind), (key, report[key])
    assert all(isinstance(t, float) for t in report["crack_times"])
    assert len(report["crack_times"]) == report["n_cracks"]
    assert report["status"] == "ok" and code == 0
    assert report["steps"] > 0 and report["wall_time_s"] > 0
    assert math.isfinite(report["mean_velocity"])
    params = report["parameters"]
    assert params["t1"] == 0.5 and params["N"] == 7
    assert params["omega"] == pytest.approx(4 * math.pi)


def test_persistent_compilation_cache_is_written(json_run, cache_dir):
    assert any(cache_dir.iterdir()), "the compiled solve should land in JAXWORM_CACHE_DIR"


def test_plot_writes_png_and_expression_values_are_parsed(capsys, cache_dir, tmp_path):
    out_dir = tmp_path / "figs" / "nested"
    code, out, err = run(capsys, "simulate", "--set", "t1=0.2", "--set", "omega=3*pi",
                         "--set", "delta=pi/3", "--plot", str(out_dir), "--json")
    report = json.loads(out)
    assert code == 0 and report["status"] == "ok"
    assert report["parameters"]["omega"] == pytest.approx(3 * math.pi, rel=1e-15)
    assert report["parameters"]["delta"] == pytest.approx(math.pi / 3, rel=1e-15)
    png = out_dir / "fig2.png"
    assert report["figure"] == str(png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_text_summary_names_velocity_cracks_status_steps_and_wall_time(capsys, json_run):
    code, out, err = run(capsys, "simulate", "--set", "t1=0.5")  # compiled by json_run
    assert code == 0
    for word in ("mean velocity", "m/s", "cracks", "status", "ok", "steps", "wall time"):
        assert word in out, (word, out)


@pytest.mark.parametrize("text, value", [
    ("4*pi", 4 * math.pi), ("pi/4", math.pi / 4), ("-pi/3", -math.pi / 3),
    ("1.4e5", 1.4e5), ("2**-3", 0.125), ("(1 + 2) * 3", 9.0), (" 13 ", 13.0),
])
def test_parse_value_accepts_numbers_and_pi_expressions(text, value):
    assert parse_value(text) == pytest.approx(value, rel=1e-15)


@pytest.mark.parametrize("text", [
    "__import__('os')", "pi.real", "abs(-1)", "e", "1/0", "10.0**400", "", "1 if 1 else 2",
    "[1]", "True", "1j",
])
def test_parse_value_rejects_anything_else(text):
    with pytest.raises(ValueError):
        parse_value(text)


def one_line_error(code, out, err):
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_unknown_parameter_exits_2_with_one_line_naming_it(capsys):
    line = one_line_error(*run(capsys, "simulate", "--set", "omegga=3"))
    assert "omegga" in line and "unknown parameter" in line


@pytest.mark.parametrize("assignment, words", [
    ("nu=0.7", ("nu", "0.7")),
    ("N=1", ("N", "1")),
    ("N=7.5", ("N", "7.5")),
    ("omega=-1", ("omega", "-1")),
    ("K_Ith=250", ("K_Ith", "250")),
    ("t1=-2", ("t1", "-2")),
    ("lam=pi/0", ("lam", "pi/0")),
    ("mu_s=os.system", ("mu_s", "os.system")),
])
def test_bad_value_exits_2_with_one_line_naming_parameter_and_value(capsys, assignment, words):
    line = one_line_error(*run(capsys, "simulate", "--set", assignment))
    for word in words:
        assert word in line, (word, line)


@pytest.mark.parametrize("argv", [
    ["simulate", "--set", "nu"],
    ["simulate", "--set", "=1"],
    ["simulate", "--solver", "Euler"],
    ["simulate", "--rtol", "-1"],
    ["simulate", "--max-cracks", "0"],
    ["simulate", "--bogus"],
    ["simulate", "--set"],
    [],
])
def test_usage_errors_exit_2_with_one_line(capsys, argv):
    one_line_error(*run(capsys, *argv))


# --- jaxworm sweep ---------------------------------------------------------------------------

def test_sweep_command_writes_a_labelled_file_and_a_rerun_resumes(capsys, tmp_path, cache_dir):
    import numpy as np

    import jaxworm as jw

    out = tmp_path / "s.npz"
    argv = ["sweep", "--grid", "omega=3*pi:5*pi:2", "--grid", "delta=pi/6,-pi/4",
            "--set", "t1=0.2", "--solver", "Rodas4", "--dt", "1e-4", "--out", str(out),
            "--chunk", "3", "--quiet"]
    code, text, err = run(capsys, *argv)
    assert code == 0, err
    s = jw.load_sweep(out)
    assert s["mean_velocity"].shape == (2, 2) and s["done"].all()
    np.testing.assert_allclose(s["coords"]["omega"], [3 * math.pi, 5 * math.pi])
    np.testing.assert_allclose(s["coords"]["delta"], [math.pi / 6, -math.pi / 4])
    single = jw.simulate(jw.Params().replace(omega=5 * math.pi, delta=-math.pi / 4), 0.2,
                         jw.Numerics(solver="Rodas4", dt=1e-4))
    np.testing.assert_allclose(s["mean_velocity"][1, 1], float(single.mean_velocity), rtol=1e-9)
    assert "4 scenes" in text and str(out) in text
    before = out.read_bytes()
    code, text, err = run(capsys, *argv)  # everything done: nothing is solved again
    assert code == 0 and out.read_bytes() == before
    fig = tmp_path / "fig3.png"
    code, text, err = run(capsys, "fig3", str(out), "--out", str(fig))
    assert code == 0, err
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    whole = tmp_path / "w.npz"  # --horizon: each scene up to its last whole period in t1
    code, text, err = run(capsys, *argv[:-5], "--out", str(whole), "--quiet",
                          "--set", "t1=0.5", "--horizon", "whole_periods")
    assert code == 0, err
    w = jw.load_sweep(whole)
    assert w["header"]["horizon"] == "whole_periods"
    h = jw.whole_period_horizon(5 * math.pi, 0.5)  # one period, 0.4 s
    single = jw.simulate(jw.Params().replace(omega=5 * math.pi, delta=-math.pi / 4), h,
                         jw.Numerics(solver="Rodas4", dt=1e-4))
    np.testing.assert_allclose(w["mean_velocity"][1, 1], float(single.mean_velocity), rtol=1e-9)


def test_fig3_refuses_a_missing_file_and_a_one_axis_sweep(capsys, tmp_path):
    import jaxworm as jw

    code, out, err = run(capsys, "fig3", str(tmp_path / "none.npz"))
    assert code == 2 and "does not exist" in err
    one = tmp_path / "one.npz"
    jw.sweep({"omega": [4 * math.pi]}, t1=0.05, numerics=jw.Numerics(solver="Rodas4", dt=1e-4),
             path=one, progress=False)
    code, out, err = run(capsys, "fig3", str(one))
    assert code == 2 and "2 parameters" in err


@pytest.mark.parametrize("argv, needle", [
    (["sweep", "--grid", "omgea=1,2"], "omgea"),
    (["sweep", "--grid", "omega=1:2"], "START:STOP:NUM"),
    (["sweep", "--grid", "t1=1,2"], "t1"),
    (["sweep", "--grid", "omega=3,x"], "omega"),
])
def test_sweep_usage_errors_exit_2_with_one_line(capsys, argv, needle):
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and needle in err


def test_python_dash_m_runs_the_command_line():
    import subprocess
    import sys
    done = subprocess.run([sys.executable, "-m", "jaxworm", "--version"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0 and jw.__version__ in done.stdout + done.stderr
