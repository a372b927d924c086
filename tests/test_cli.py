"""The `jaxworm` command line, called in-process (`main([...])`): `simulate` and `sweep`
end to end, the value parser, the parameter table, and every command's usage errors in
one table.

Two simulate solves, to keep this file short: a summary run (t1 = 0.5 s) and a dense run
with a figure (t1 = 0.2 s, omega = 3*pi). Usage errors never reach a solve.
"""

import json
import math

import pytest

import jaxworm as jw
from jaxworm._cli import main, parse_value

SUMMARY_KEYS = {
    "mean_velocity": float,
    "n_cracks": int,
    "crack_times": list,
    "final_head": float,
    "final_crack_tip": float,
    "status": str,
    "steps": int,
    "wall_time_s": float,
    "energy_residual": float,
    "parameters": dict,
}


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
    compiled = cache_dir / "jax"
    assert compiled.is_dir() and any(compiled.iterdir()), (
        "the compiled solve should land in JAXWORM_CACHE_DIR/jax"
    )


def test_plot_writes_png_and_expression_values_are_parsed(capsys, cache_dir, tmp_path):
    out_dir = tmp_path / "figs" / "nested"
    code, out, err = run(
        capsys,
        "simulate",
        "--set",
        "t1=0.2",
        "--set",
        "omega=3*pi",
        "--set",
        "delta=pi/3",
        "--plot",
        str(out_dir),
        "--json",
    )
    report = json.loads(out)
    assert code == 0 and report["status"] == "ok"
    assert report["parameters"]["omega"] == pytest.approx(3 * math.pi, rel=1e-15)
    assert report["parameters"]["delta"] == pytest.approx(math.pi / 3, rel=1e-15)
    png = out_dir / "fig2.png"
    assert report["figure"] == str(png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert [p.name for p in out_dir.iterdir()] == ["fig2.png"]  # what --help promises
    assert main(["simulate", "--help"]) == 0
    usage = " ".join(capsys.readouterr().out.split())
    assert "to DIR/fig2.png (or .pdf, --format)" in usage and "save dense output" not in usage


def test_text_summary_names_velocity_cracks_status_steps_and_wall_time(capsys, json_run):
    code, out, err = run(capsys, "simulate", "--set", "t1=0.5")  # compiled by json_run
    assert code == 0
    for word in ("mean velocity", "m/s", "cracks", "status", "ok", "steps", "wall time"):
        assert word in out, (word, out)


@pytest.mark.parametrize(
    "text, value",
    [
        ("4*pi", 4 * math.pi),
        ("pi/4", math.pi / 4),
        ("-pi/3", -math.pi / 3),
        ("1.4e5", 1.4e5),
        ("2**-3", 0.125),
        ("(1 + 2) * 3", 9.0),
        (" 13 ", 13.0),
    ],
)
def test_parse_value_accepts_numbers_and_pi_expressions(text, value):
    assert parse_value(text) == pytest.approx(value, rel=1e-15)


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os')",
        "pi.real",
        "abs(-1)",
        "e",
        "1/0",
        "10.0**400",
        "",
        "1 if 1 else 2",
        "[1]",
        "True",
        "1j",
    ],
)
def test_parse_value_rejects_anything_else(text):
    with pytest.raises(ValueError):
        parse_value(text)


# --- jaxworm sweep ---------------------------------------------------------------------------


def test_sweep_command_writes_a_labelled_file_and_a_rerun_resumes(capsys, tmp_path, cache_dir):
    import numpy as np

    import jaxworm as jw

    out = tmp_path / "s.npz"
    argv = [
        "sweep",
        "--grid",
        "omega=3*pi:5*pi:2",
        "--grid",
        "delta=pi/6,-pi/4",
        "--set",
        "t1=0.2",
        "--solver",
        "Rodas4",
        "--dt",
        "1e-4",
        "--out",
        str(out),
        "--chunk",
        "3",
        "--quiet",
    ]
    code, text, err = run(capsys, *argv)
    assert code == 0, err
    s = jw.load_sweep(out)
    assert s["mean_velocity"].shape == (2, 2) and s["done"].all()
    np.testing.assert_allclose(s["coords"]["omega"], [3 * math.pi, 5 * math.pi])
    np.testing.assert_allclose(s["coords"]["delta"], [math.pi / 6, -math.pi / 4])
    single = jw.simulate(
        jw.Params().replace(omega=5 * math.pi, delta=-math.pi / 4),
        0.2,
        jw.Numerics(solver="Rodas4", dt=1e-4),
    )
    np.testing.assert_allclose(s["mean_velocity"][1, 1], float(single.mean_velocity), rtol=1e-9)
    assert "4 scenes" in text and str(out) in text
    before = out.read_bytes()
    code, text, err = run(capsys, *argv)  # everything done: nothing is solved again
    assert code == 0 and out.read_bytes() == before
    fig = tmp_path / "fig3.png"
    code, text, err = run(capsys, "fig3", str(out), "--out", str(fig))
    assert code == 0, err
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # An unfinished sweep (as a killed one leaves it) is drawn, blank where unsolved, and
    # the command says so and exits 1: not every scene ended ok.
    from jaxworm import _sweep

    part, done = tmp_path / "part.npz", s["done"].copy()
    done[1, 1] = False
    fields = {n: s[n] for n in _sweep.SWEEP_FIELDS}
    _sweep._save(part, s["header"], s["coords"], fields, done)
    code, text, err = run(capsys, "fig3", str(part), "--out", str(tmp_path / "part.png"))
    assert code == 1 and "unfinished (3 of 4 scenes solved)" in text, (code, text, err)
    assert (tmp_path / "part.png").exists()
    failed = tmp_path / "failed.npz"  # finished, one scene not ok
    status = s["status"].copy()
    status[0, 1] = {v: k for k, v in jw.STATUS.items()}["max_steps_reached"]
    _sweep._save(failed, s["header"], s["coords"], {**fields, "status": status}, s["done"])
    code, text, err = run(capsys, "fig3", str(failed), "--out", str(tmp_path / "failed.png"))
    assert code == 1 and "1 scene(s) did not end ok" in text, (code, text, err)
    whole = tmp_path / "w.npz"  # --horizon: each scene up to its last whole period in t1
    code, text, err = run(
        capsys,
        *argv[:-5],
        "--out",
        str(whole),
        "--quiet",
        "--set",
        "t1=0.7",  # one period of the slowest gait (3π rad/s: 0.67 s) fits
        "--horizon",
        "whole_periods",
    )
    assert code == 0, err
    w = jw.load_sweep(whole)
    assert w["header"]["horizon"] == "whole_periods"
    h = jw.whole_period_horizon(5 * math.pi, 0.7)  # one period, 0.4 s
    single = jw.simulate(
        jw.Params().replace(omega=5 * math.pi, delta=-math.pi / 4),
        h,
        jw.Numerics(solver="Rodas4", dt=1e-4),
    )
    np.testing.assert_allclose(w["mean_velocity"][1, 1], float(single.mean_velocity), rtol=1e-9)


def test_a_one_axis_sweep_is_refused_by_fig3_and_by_optimise_before_it_solves(
    capsys, tmp_path, monkeypatch
):
    import jaxworm as jw

    one = tmp_path / "one.npz"
    jw.sweep(
        {"omega": [4 * math.pi]},
        t1=0.05,
        numerics=jw.Numerics(solver="Rodas4", dt=1e-4),
        path=one,
        progress=False,
        chunk=4000,
    )
    # A chunk is padded to its size: one larger than the grid is cut to the grid's (a
    # chunk of 4000 for 2 scenes took 6x the time of a chunk of 2).
    assert jw.load_sweep(one)["header"]["chunk"] == 1
    code, out, err = run(capsys, "fig3", str(one))
    assert code == 2 and "2 parameters" in err
    # As the heatmap of an optimisation over other parameters, it is refused before the
    # optimisation runs (it was refused when drawn, after every step had been solved).
    monkeypatch.setattr(jw, "optimise", _solve_called)
    out_file, plot = tmp_path / "o.npz", tmp_path / "p.png"
    code, out, err = run(
        capsys,
        *("optimise", "--quiet", "--out", str(out_file), "--plot", str(plot)),
        *("--heatmap", str(one)),
    )
    assert code == 2 and out == "", err
    assert "--heatmap: plot_optimisation: the sweep's axes ['omega']" in err
    assert not out_file.exists() and not plot.exists()


def _solve_called(*args, **kwargs):
    raise AssertionError("a solve was started")


def test_an_unwritable_figure_file_is_refused_before_the_solve(capsys, tmp_path, monkeypatch):
    # A read-only (or immutable) fig2.png was found when drawing, after the solve, with
    # only the OS error's text. The check opens the file for appending: refused here by
    # a stand-in for that open (a root user can write a chmod 444 file).
    from jaxworm._cli import outputs

    folder = tmp_path / "plots"
    folder.mkdir()
    (folder / "fig2.png").write_bytes(b"keep")

    def refuse(path, mode="r", *args, **kwargs):
        if set(mode) & set("wax+"):
            raise PermissionError(13, "Permission denied", str(path))
        return open(path, mode, *args, **kwargs)

    monkeypatch.setattr(outputs, "open", refuse, raising=False)
    monkeypatch.setattr(jw, "simulate", _solve_called)
    code, out, err = run(capsys, "simulate", "--set", "t1=0.1", "--plot", str(folder))
    assert code == 2 and out == "", err
    assert f"--plot {str(folder / 'fig2.png')!r}: cannot write this file (Permission" in err
    assert (folder / "fig2.png").read_bytes() == b"keep"


def test_help_and_version_return_zero_when_main_is_called_from_python(capsys):
    assert main(["--version"]) == 0 and jw.__version__ in capsys.readouterr().out
    assert main(["fig3", "--help"]) == 0 and "sweep_file" in capsys.readouterr().out


def test_grid_ranges_are_numpys_so_the_cli_resumes_the_apis_sweep_file():
    # The CLI's START:STOP:NUM once differed from np.linspace in the last bit: a sweep
    # file written by the Python API was "a different sweep" to the command line.
    import numpy as np

    from jaxworm._cli.values import parse_grid

    grid = parse_grid(["omega=3*pi:5*pi:7", "delta=-pi/3:-pi/6:11"])
    assert grid["omega"] == np.linspace(3 * np.pi, 5 * np.pi, 7).tolist()
    assert grid["delta"] == np.linspace(-np.pi / 3, -np.pi / 6, 11).tolist()
    paper = jw.paper.paper_grid(21)  # the default grid is the paper's, bit for bit
    assert {n: np.asarray(v).tobytes() for n, v in parse_grid([]).items()} == {
        n: v.tobytes() for n, v in paper.items()
    }


def test_a_sweep_summary_names_the_statuses_that_are_not_ok_and_what_to_do():
    from jaxworm._cli.commands.sweep import _not_ok

    code = {name: c for c, name in jw.STATUS.items()}
    text = _not_ok([code["too_many_cracks"], code["body_inverted"], code["body_inverted"]])
    assert text.startswith("2 body_inverted, 1 too_many_cracks (body_inverted: a segment")


def test_python_dash_m_runs_the_command_line():
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "jaxworm", "--version"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0 and jw.__version__ in done.stdout + done.stderr


# --- usage errors: exit 2, one line on stderr naming what is wrong, before any solve -------

USAGE_ERRORS = [
    # (argv, exit code, a substring of the one line on stderr)
    ([], 2, "the following arguments are required: COMMAND"),
    # simulate: --set NAME=VALUE
    (["simulate", "--set", "omegga=3"], 2, "unknown parameter 'omegga' in --set omegga=3"),
    (["simulate", "--set", "nu=0.7"], 2, "parameter nu = 0.7 is out of range"),
    (["simulate", "--set", "N=1"], 2, "parameter N = 1 is out of range"),
    (["simulate", "--set", "N=7.5"], 2, "parameter N = 7.5 is not an integer"),
    (["simulate", "--set", "omega=-1"], 2, "parameter omega = -1.0 is out of range"),
    (["simulate", "--set", "K_Ith=250"], 2, "parameter K_Ith = 250.0 is out of range"),
    (["simulate", "--set", "t1=-2"], 2, "parameter t1 = -2.0 is out of range"),
    (["simulate", "--set", "lam=pi/0"], 2, "--set lam=pi/0: bad value 'pi/0'"),
    (["simulate", "--set", "mu_s=os.system"], 2, "--set mu_s=os.system: bad value 'os.system'"),
    (["simulate", "--set", "nu"], 2, "--set 'nu' is malformed: need NAME=VALUE"),
    (["simulate", "--set", "=1"], 2, "--set '=1' is malformed: need NAME=VALUE"),
    (["simulate", "--set"], 2, "argument --set: expected one argument"),
    # simulate: numerics and unknown options
    (["simulate", "--solver", "Euler"], 2, "argument --solver: invalid choice: 'Euler'"),
    (["simulate", "--rtol", "-1"], 2, "--rtol -1 is out of range: need 0 <= rtol < 1"),
    (["simulate", "--rtol", "1"], 2, "--rtol 1 is out of range: need 0 <= rtol < 1"),
    (
        ["simulate", "--max-cracks", "0"],
        2,
        "--max-cracks 0 is out of range: need 1 <= max-cracks <= 10000",
    ),
    (["simulate", "--max-cracks", "10001"], 2, "need 1 <= max-cracks <= 10000"),
    (["simulate", "--bogus"], 2, "unrecognized arguments: --bogus"),
    # sweep and fig3
    (["sweep", "--grid", "omgea=1,2"], 2, "grid parameter 'omgea' is unknown"),
    (["sweep", "--grid", "omega=1:2"], 2, "--grid omega=1:2: need START:STOP:NUM"),
    (["sweep", "--grid", "t1=1,2"], 2, "grid parameter 't1' is unknown"),
    (["sweep", "--grid", "omega=3,x"], 2, "--grid omega=3,x: only numbers, pi"),
    (
        ["sweep", "--grid", "omega=" + ",".join(["1"] * 10_001)],
        2,
        "10001 values are too many: need at most 10000 per axis",
    ),
    (["sweep", "--coordinator", "127.0.0.1:1"], 2, "go together"),
    (
        ["sweep", "--coordinator", "h:1", "--num-processes", "2", "--process-id", "2"],
        2,
        "--process-id 2: need 0 <= process-id < --num-processes (2)",
    ),
    (["sweep", "--distributed", "--num-processes", "2"], 2, "--distributed finds"),
    (
        ["sweep", "--coordinator", "nonsense", "--num-processes", "2", "--process-id", "0"],
        2,
        "--coordinator 'nonsense' is not HOST:PORT: need a host name or IP address and a "
        "port in 1..65535",
    ),
    (
        ["optimise", "--coordinator", "h:99999", "--num-processes", "2", "--process-id", "0"],
        2,
        "--coordinator 'h:99999' is not HOST:PORT",
    ),
    (
        ["sweep", "--grid", "omega=1:2:10000", "--grid", "delta=0:1:10000", "--out", "h.npz"],
        2,
        "grid (omega 10000 x delta 10000) has 100000000 scenes, more than the limit of "
        "1000000 scenes",
    ),
    (
        ["sweep", "--grid", "omega=1,2", "--set", "omega=3"],
        2,
        "parameter omega is both fixed (--set) and swept (--grid)",
    ),
    (["sweep", "--set", "delta=1"], 2, "parameter delta is both fixed (--set) and swept"),
    (["sweep", "--workers", "100000"], 2, "--workers 100000 is out of range"),
    (["sweep", "--out", "nonexist/s.npz"], 2, "its folder 'nonexist' does not exist"),
    (["optimise", "--num-processes", "0"], 2, "--num-processes 0 is out of range: need >= 1"),
    (["sweep", "--process-id", "-1"], 2, "--process-id -1 is out of range: need >= 0"),
    (["fig3", "missing.npz"], 2, "sweep file 'missing.npz' does not exist"),
    # optimise
    (["optimise", "--quiet", "--bound", "omega=1:2:3"], 2, "--bound 'omega=1:2:3' is malformed"),
    (["optimise", "--quiet", "--bound", "foo=1:2"], 2, "unknown parameter 'foo'"),
    (["optimise", "--quiet", "--bound", "delta=x:1"], 2, "--bound delta=x:1"),
    (["optimise", "--quiet", "--bound", "omega=2:1"], 2, "bounds for omega = (2.0, 1.0)"),
    (["optimise", "--quiet", "--dt", "1e-4"], 2, "dt = 0.0001: derivatives need"),
    (
        ["optimise", "--quiet", "--set", "delta=1", "--bound", "delta=0:1"],
        2,
        "parameter delta is both fixed (--set) and optimised (--bound)",
    ),
    (["optimise", "--quiet", "--steps", "0"], 2, "--steps 0 is out of range"),
    # Sizes a history is allocated for: refused, not a MemoryError after the parse.
    (["optimise", "--quiet", "--steps", "10**12"], 2, "--steps '10**12' is not an integer"),
    (["optimise", "--quiet", "--steps", "1000000000000"], 2, "need 1 <= steps <= 10000"),
    (["optimise", "--quiet", "--starts", "4097"], 2, "need 1 <= starts <= 4096"),
    (
        ["optimise", "--quiet", "--bound", "K_Ic=200:300"],
        2,
        "bounds for K_Ic = (200.0, 300.0): the scene at K_Ic = 200.0 is invalid: parameter K_Ith",
    ),
    (
        ["optimise", "--quiet", "--bound", "omega=1:2", "--bound", "omega=3:4"],
        2,
        "--bound omega=3:4: parameter omega is given twice",
    ),
    (
        ["optimise", "--quiet", "--heatmap", "missing.npz", "--plot", "p.png"],
        2,
        "sweep file 'missing.npz' does not exist",
    ),
    (["optimise", "--quiet", "--heatmap", "missing.npz"], 2, "--heatmap needs --plot"),
    (["optimise", "--quiet", "--box", "tanh"], 2, "invalid choice: 'tanh'"),
    (["optimise", "--quiet", "--horizon", "cycles"], 2, "invalid choice: 'cycles'"),
    (
        ["optimise", "--quiet", "--optimiser", "sgd", "--b1", "0.5"],
        2,
        "--b1 = 0.5: only adam and adabelief have a momentum b1, not sgd",
    ),
    (
        ["optimise", "--quiet", "--optimiser", "rprop", "--b1", "0.5"],
        2,
        "--b1 = 0.5: only adam and adabelief have a momentum b1, not rprop",
    ),
    (["optimise", "--quiet", "--b1", "1"], 2, "--b1 1 is out of range"),
    # fig2, animate, paper
    (["fig2", "--set", "delta=pi/0"], 2, "--set delta=pi/0: bad value 'pi/0'"),
    (["fig2", "--set", "omega=-1"], 2, "parameter omega = -1.0 is out of range"),
    (["fig2", "--out", "f.svg"], 2, "--out f.svg: the figure suffix must be .png or .pdf"),
    (["fig2", "--out", "f.png", "--format", "pdf"], 2, "--out f.png does not match --format pdf"),
    (["fig2", "--points", "0"], 2, "--points 0 is out of range"),
    (["fig2", "--points", "1"], 2, "--points 1 is out of range: need 2 <= points <= 100000"),
    # A size that aborted the process in XLA (exit 134) is a usage error.
    (["fig2", "--points", "1000000000000"], 2, "need 2 <= points <= 100000"),
    (["animate", "--frames", "1000000000000"], 2, "need 1 <= frames <= 10000"),
    (["fig2", "--out", "."], 2, "--out '.' is a folder: give a file such as 'fig2.png'"),
    (["fig2", "--out", "nonexist/f.png"], 2, "folder 'nonexist' does not exist"),
    # A trailing separator names a folder (Path would drop it and write a file there).
    (["sweep", "--out", "new.npz/"], 2, "--out 'new.npz/' ends with '/', so it names a folder"),
    (["sweep", "--plot", "s.png/"], 2, "--plot 's.png/' ends with '/', so it names a folder"),
    (["optimise", "--out", "o.npz/"], 2, "--out 'o.npz/' ends with '/'"),
    (["optimise", "--plot", "o.png/"], 2, "--plot 'o.png/' ends with '/'"),
    (["fig2", "--out", "f.png/"], 2, "--out 'f.png/' ends with '/'"),
    (["fig3", "s.npz", "--out", "f.png/"], 2, "--out 'f.png/' ends with '/'"),
    (["animate", "--out", "w.gif/"], 2, "--out 'w.gif/' ends with '/'"),
    (["animate", "--out", "nonexist/w.gif"], 2, "folder 'nonexist' does not exist"),
    (["optimise", "--quiet", "--out", "nonexist/o.npz"], 2, "folder 'nonexist' does not exist"),
    (
        ["animate", "--out", "worm.avi"],
        2,
        "--out worm.avi: the animation suffix must be .gif or .mp4",
    ),
    (["animate", "--fps", "0"], 2, "--fps 0 is out of range"),
    (["animate", "--fps", "60"], 2, "--fps = 60: a GIF plays at most 50 frames per second"),
    (["paper", "--size", "1"], 2, "--size 1 is out of range: need 2 <= size <= 1000"),
    (["paper", "--size", "1001"], 2, "--size 1001 is out of range: need 2 <= size <= 1000"),
    (["paper", "--set", "K_Ith=300"], 2, "parameter K_Ith = 300.0 is out of range"),
    (["paper", "--mirror", "--reading", "model"], 2, "--mirror and --reading model contradict"),
    (["paper", "--reading", "tail"], 2, "invalid choice: 'tail'"),
]


@pytest.mark.parametrize(
    "argv, code, message",
    USAGE_ERRORS,
    ids=[" ".join(argv) or "(no command)" for argv, _, _ in USAGE_ERRORS],
)
def test_usage_error_exits_with_one_line_naming_it_and_writes_nothing(
    capsys, cache_dir, tmp_path, monkeypatch, argv, code, message
):
    monkeypatch.chdir(tmp_path)
    got, out, err = run(capsys, *argv)
    assert got == code and out == "", (got, out, err)
    assert err.startswith("jaxworm: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "argv, message",
    [
        (["simulate", "--plot", "ref.npz"], "--plot 'ref.npz' is a file, not a folder"),
        (["paper", "--out", "ref.npz"], "--out 'ref.npz' is a file, not a folder"),
        (["fig2", "--out", "ref.npz/f.png"], "--out 'ref.npz/f.png': 'ref.npz' is a file"),
        (["sweep", "--out", "ref.npz/s.npz"], "'ref.npz', where its folder should be, is a file"),
    ],
)
def test_a_folder_option_naming_a_file_is_a_usage_error_naming_it(
    capsys, monkeypatch, tmp_path, argv, message
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "ref.npz").write_bytes(b"keep")
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == "" and err.count("\n") == 1 and message in err, err
    assert "Errno" not in err and (tmp_path / "ref.npz").read_bytes() == b"keep"
    assert [p.name for p in tmp_path.iterdir()] == ["ref.npz"]


class _Computed(Exception):
    """Raised in place of `paper`'s first solve: the outputs' checks were passed."""


def _no_paper_solve(monkeypatch):
    def computed(*args, **kwargs):
        raise _Computed

    monkeypatch.setattr("jaxworm._cli.commands.paper.dense_run", computed)
    monkeypatch.setattr("jaxworm._sweep._run_chunk", computed)


def test_paper_checks_every_output_before_computing_and_overwrite_lets_it_run(
    capsys, monkeypatch, tmp_path
):
    import numpy as np

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    out = tmp_path / "pout"
    out.mkdir()
    # The mirrored grid's file, the second checked, holds the same grid over t1 = 1 s.
    grid = jw.paper.paper_grid(2, delta_sign=-1)

    def fake_chunk(base, names, values, t1, numerics, horizon="t1"):
        return {n: np.zeros(len(values)) for n in jw.SWEEP_FIELDS}

    from jaxworm._cli.parser import build_parser
    from jaxworm._cli.scenes import scene

    monkeypatch.setattr("jaxworm._sweep._run_chunk", fake_chunk)
    argv = ["paper", "--size", "2", "--set", "t1=0.5", "--out", "pout", "--quiet"]
    # The model reading's file holds this very run's grid, as `paper` sweeps it: resumed.
    params, t1, numerics = scene(build_parser().parse_args(argv))
    jw.sweep(
        jw.paper.paper_grid(2), params, t1, numerics, path=out / "fig3_2x2.npz", progress=False
    )
    data = out / "fig3_2x2_mirrored.npz"
    jw.sweep(grid, t1=1.0, path=data, progress=False)
    before = data.read_bytes()
    (out / "fig2.png").write_bytes(b"old figure")
    _no_paper_solve(monkeypatch)
    code, text, err = run(capsys, *argv)
    assert code == 2 and text == "" and err.count("\n") == 1, err
    assert "fig3_2x2_mirrored.npz" in err and "different sweep (t1 differ)" in err
    assert "--overwrite" in err
    assert data.read_bytes() == before and (out / "fig2.png").read_bytes() == b"old figure"
    files = ["fig2.png", "fig3_2x2.npz", "fig3_2x2_mirrored.npz"]
    assert sorted(p.name for p in out.iterdir()) == files
    with pytest.raises(_Computed):  # the model reading alone: its file is this run's
        main([*argv, "--reading", "model"])
    with pytest.raises(_Computed):  # the fix the message suggests: on to the solves
        main([*argv, "--overwrite"])
    with pytest.raises(_Computed):  # a missing --out folder is created (README quick start)
        main(["paper", "--size", "2", "--out", "fresh/out", "--quiet"])
    assert (tmp_path / "fresh" / "out").is_dir()


def test_distributed_without_a_cluster_in_the_environment_is_a_usage_error(
    capsys, monkeypatch, tmp_path
):
    from jaxworm._cli.runtime import cluster_in_environment

    monkeypatch.chdir(tmp_path)
    for name in ("JAX_COORDINATOR_ADDRESS", "SLURM_JOB_ID", "OMPI_MCA_orte_hnp_uri"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.delenv("KUBERNETES_SERVICE_HOST", raising=False)
    for command in ("sweep", "optimise"):
        code, out, err = run(capsys, command, "--distributed", "--quiet")
        assert code == 2 and out == "" and err.count("\n") == 1, err
        assert "--distributed: no cluster found in the environment" in err
        assert "--coordinator HOST:PORT" in err
    assert list(tmp_path.iterdir()) == []
    slurm = {  # what SLURM sets for each task: JAX's own detection finds it
        "SLURM_JOB_ID": "1",
        "SLURM_STEP_NODELIST": "node1",
        "SLURM_NTASKS": "2",
        "SLURM_PROCID": "0",
        "SLURM_LOCALID": "0",
    }
    for name, value in slurm.items():
        monkeypatch.setenv(name, value)
    assert cluster_in_environment()


def test_animate_mp4_without_ffmpeg_is_a_usage_error(capsys, monkeypatch, tmp_path):
    monkeypatch.setattr("jaxworm._animate.ffmpeg_available", lambda: False)
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, "animate", "--out", "worm.mp4")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "--out worm.mp4: MP4 needs ffmpeg" in err


# --- the parameter table: derived from jaxworm's one table of parameter facts ---------------

#: `jaxworm simulate --set` names: (unit, default as shown, description), in this order.
CLI_PARAMETERS = {
    "N": ("-", "7", "number of nodes (integer >= 2)"),
    "E_s": ("Pa", "1.4e5", "soil elasticity"),
    "K_Ic": ("Pa·√m", "250", "critical stress intensity factor"),
    "K_Ith": ("Pa·√m", "200", "threshold stress intensity factor (< K_Ic)"),
    "nu": ("-", "0.3", "Poisson's ratio, in [0, 0.5)"),
    "w_c": ("m", "1e-3", "crack width"),
    "Wg": ("-", "4.59e-4", "wedge number"),
    "EA": ("N", "13", "stretching stiffness (Table 1 writes Pa·m²)"),
    "w0": ("m", "1e-3", "unstretched segment width"),
    "l0": ("m", "1e-2", "unstretched segment length"),
    "h": ("m", "1e-3", "planar thickness"),
    "m": ("kg", "1e-5", "mass per segment"),
    "mu_s": ("-", "0.3", "sliding friction coefficient"),
    "lam": ("-", "1.5", "friction anisotropy multiplier (>= 1)"),
    "A": ("m/s", "0.02", "gait amplitude"),
    "omega": ("rad/s", "4*pi", "gait angular frequency (> 0)"),
    "delta": ("rad", "pi/4", "gait phase offset between segments"),
    "t1": ("s", "60", "simulated horizon (not a model parameter)"),
    "eps_v": ("m/s", "1e-4", "smoothing scale of sgn: tanh(v/eps_v)"),
    "eps_N": ("N", "1e-8", "smoothing scale of max in the normal force"),
    "crack_gap0": ("m", "eq. 13", "initial crack tip distance ahead of the head"),
}


def test_cli_parameter_table_is_the_model_table_and_t1_in_table1_order():
    from jaxworm._cli.values import PARAMETERS

    assert list(PARAMETERS.items()) == list(CLI_PARAMETERS.items())
    assert set(PARAMETERS) == set(jw.FLAT_NAMES) | {"t1"}


def test_each_default_shown_given_to_set_is_the_default():
    from jaxworm._cli.values import DEFAULT_T1, PARAMETERS

    flat = jw.Params().flat()
    for name, (_, shown, _) in PARAMETERS.items():
        default = DEFAULT_T1 if name == "t1" else flat[name]
        if default is None:  # crack_gap0: placed by eq. 13
            assert shown == "eq. 13"
        else:
            assert parse_value(shown) == pytest.approx(float(default), rel=1e-15), name


def test_simulate_help_lists_every_parameter_with_unit_description_and_default(capsys):
    assert main(["simulate", "--help"]) == 0
    lines = capsys.readouterr().out.splitlines()
    listed = [line for line in lines if line.startswith("  ") and " [" in line[:14]]
    assert listed == [
        f"  {n:<10} [{u}] {d} (default {v})" for n, (u, v, d) in CLI_PARAMETERS.items()
    ]


def test_reading_options_reach_the_scene_and_default_to_the_printed_reading():
    from jaxworm._cli.parser import build_parser
    from jaxworm._cli.scenes import READINGS, scene

    parse = build_parser().parse_args
    params, _, _ = scene(parse(["simulate"]))
    assert params == jw.Params()
    for name in READINGS:
        choice = jw.MODEL_OPTIONS[name].choices[-1]
        flag = f"--{name.replace('_', '-')}"
        params, _, _ = scene(parse(["simulate", flag, choice]))
        assert params.options()[name] == choice
        assert params == jw.Params().replace(**{name: choice})
