"""Reproducing the paper: `jaxworm fig2`, `jaxworm animate`, `jaxworm paper` and the
comparison with the paper's numbers (`jaxworm._reproduction`), and the frame geometry of
the animation (`jaxworm._animate`).

One compiled solve in all: `fig2` and `animate` both run t1 = 0.2 s with 5 dense times,
so the second reuses the first's program. The comparison is checked on a made-up sweep;
the commands' usage errors are in test_cli.py.
"""

import math
import types

import numpy as np
import pytest

from jaxworm._animate import frame_geometry
from jaxworm._cli import main
from jaxworm._reproduction import (
    PAPER,
    compare_with_paper,
    format_comparison,
    format_readings,
    mirror_sweep,
    paper_grid,
    zero_crossing,
)

SHORT = ["--set", "t1=0.2"]


# A private jaxworm cache folder for this module's runs (conftest's `cache_dir`).
pytestmark = pytest.mark.usefixtures("cache_dir")


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# --- the commands ------------------------------------------------------------------------


def test_fig2_writes_a_pdf_on_request_and_exits_0(tmp_path, capsys):
    (tmp_path / "figs").mkdir()  # a single-file output's folder must exist (docs/cli.md)
    code, out, err = run(
        capsys,
        "fig2",
        *SHORT,
        "--points",
        "5",
        "--format",
        "pdf",
        "--out",
        str(tmp_path / "figs" / "f2"),
    )
    path = tmp_path / "figs" / "f2.pdf"
    assert code == 0, err
    assert path.read_bytes()[:4] == b"%PDF"
    assert str(path) in out and "mean velocity" in out and "cracks" in out


def test_animate_writes_a_gif_with_one_image_per_frame(tmp_path, capsys):
    from PIL import Image

    path = tmp_path / "worm.gif"
    code, out, err = run(
        capsys, "animate", *SHORT, "--frames", "5", "--fps", "5", "--out", str(path)
    )
    assert code == 0, err
    with Image.open(path) as im:
        assert im.format == "GIF" and im.n_frames == 5


def test_animate_takes_numpy_integer_options_and_refuses_a_bool():
    from jaxworm import Params
    from jaxworm._animate import animate

    run_ = types.SimpleNamespace(trajectory=types.SimpleNamespace(x=np.zeros((3, 7))))
    # NumPy integers pass the option checks (then the suffix check refuses .avi); they
    # were refused as out of range, while True was taken as fps = 1.
    with pytest.raises(ValueError, match="suffix must be .gif or .mp4"):
        animate(run_, Params(), "w.avi", fps=np.int64(5), max_frames=np.int32(10))
    with pytest.raises(TypeError, match="option fps = True"):
        animate(run_, Params(), "w.gif", fps=True)
    with pytest.raises(ValueError, match="option max_frames = 0 is out of range"):
        animate(run_, Params(), "w.gif", max_frames=0)


def test_fig2_refuses_params_of_another_body(tmp_path):
    from jaxworm import Params
    from jaxworm.plot import plot_fig2

    seven = types.SimpleNamespace(trajectory=types.SimpleNamespace(x=np.zeros((3, 7))))
    with pytest.raises(ValueError, match="the result has 7 nodes and params N = 5"):
        plot_fig2(seven, Params().replace(N=5), tmp_path / "f.png")


# --- the animation's geometry ----------------------------------------------------------


def test_frame_widths_follow_eq6_and_open_the_crack_only_where_wider():
    x = np.array([0.0, -0.012, -0.020, -0.031])  # lengths 12, 8, 11 mm
    g = frame_geometry(x, 0.05, w0=1e-3, l0=1e-2, w_c=1e-3)
    np.testing.assert_allclose(g["length"], [0.012, 0.008, 0.011])
    np.testing.assert_allclose(g["width"], 1e-5 / g["length"])  # w = w0 l0 / l (eq. 6)
    np.testing.assert_allclose(g["opening"], np.maximum(g["width"], 1e-3))
    assert g["compressed"].tolist() == [False, True, False]
    np.testing.assert_allclose(g["left"], x[1:])


# --- comparison with the paper -----------------------------------------------------------


def _made_up_sweep(velocity, status=None):
    grid = paper_grid(3)
    v = np.asarray(velocity, float)
    return {
        "header": {"axes": ["omega", "delta"], "t1": 60.0, "units": {}},
        "coords": grid,
        "mean_velocity": v,
        "status": np.zeros(v.shape) if status is None else status,
    }


def test_paper_grid_spans_the_papers_window_and_mirrors_delta():
    g = paper_grid(21)
    assert g["omega"][[0, -1]].tolist() == pytest.approx([3 * math.pi, 5 * math.pi])
    assert g["delta"][[0, -1]].tolist() == pytest.approx([math.pi / 6, math.pi / 3])
    m = paper_grid(5, delta_sign=-1)["delta"]
    assert m[0] == pytest.approx(-math.pi / 3) and np.all(np.diff(m) > 0)
    with pytest.raises(ValueError, match="size"):
        paper_grid(1)


def test_zero_crossing_is_interpolated_and_nan_without_a_sign_change():
    assert zero_crossing([0.5, 0.7, 0.9], [-2.0, -1.0, 1.0]) == pytest.approx(0.8)
    assert math.isnan(zero_crossing([0.5, 0.7], [-1.0, -0.5]))


def test_a_sweep_like_the_papers_agrees_on_every_row():
    # rows: omega = 3pi, 4pi, 5pi; columns: delta = pi/6, pi/4, pi/3.
    v = [[-0.0137, 0.001, 0.0108], [-0.008, 0.0022, 0.006], [-0.004, 0.0005, 0.004]]
    rows = compare_with_paper(_made_up_sweep(v), nominal_velocity=0.0022, nominal_cracks=3)
    assert [r["agree"] for r in rows] == [True] * len(rows), rows
    assert "3 cracks" in rows[0]["ours"]
    table = format_comparison(rows, markdown=True)
    assert table.count("\n") == len(rows) + 1 and "| fastest forward |" in table
    assert all(line.replace("\\|", "").count("|") == 5 for line in table.splitlines())


def test_an_all_retreating_sweep_disagrees_and_failed_scenes_do_not_count():
    v = np.full((3, 3), -0.005)
    status = np.zeros((3, 3))
    v[0, 0], status[0, 0] = 1.0, 7  # a failed scene, not a forward gait
    rows = {r["what"]: r for r in compare_with_paper(_made_up_sweep(v, status))}
    assert rows["fastest forward"]["agree"] is False
    assert rows["fastest forward"]["ours"].startswith("none")
    assert rows["retreat for δ below"]["ours"] == "all retreat"
    assert PAPER["nominal"]["mean_velocity"] == 0.0022


def test_mirror_sweep_flips_delta_and_every_grid_field_together():
    grid = paper_grid(3, delta_sign=-1)
    v = np.arange(9.0).reshape(3, 3)
    s = {
        "header": {"axes": ["omega", "delta"]},
        "coords": grid,
        "mean_velocity": v,
        "status": np.zeros((3, 3)),
        "n_cracks": v + 10,
    }
    m = mirror_sweep(s)
    np.testing.assert_allclose(m["coords"]["delta"], paper_grid(3)["delta"])
    assert m["mean_velocity"][0].tolist() == [2.0, 1.0, 0.0]  # δ = −π/6 first
    assert m["n_cracks"][0].tolist() == [12.0, 11.0, 10.0]
    with pytest.raises(ValueError, match="delta <= 0"):
        mirror_sweep(m)


def test_format_readings_puts_each_readings_value_beside_the_papers():
    v = [[-0.0137, 0.001, 0.0108], [-0.008, 0.0022, 0.006], [-0.004, 0.0005, 0.004]]
    good = compare_with_paper(_made_up_sweep(v), nominal_velocity=0.0022)
    bad = compare_with_paper(_made_up_sweep(np.full((3, 3), -0.005)))  # no nominal row
    table = format_readings({"MODEL.md": bad, "mirrored": good}, markdown=True)
    lines = table.splitlines()
    assert lines[0] == "| | paper | MODEL.md | agree | mirrored | agree |"
    assert len(lines) == 2 + len(good)
    nominal = next(line for line in lines if line.startswith("| nominal"))
    assert nominal.split(" | ")[2:] == ["–", "–", "+0.0022 m/s", "yes |"]
    text = format_readings({"MODEL.md": bad, "mirrored": good})
    lines = text.splitlines()
    assert len(lines) == 3 * len(good) and lines[0] == "  nominal gait (4π, π/4): paper +0.0022 m/s"
    assert lines[1].split() == ["MODEL.md", "–", "agree:", "–"]
    assert lines[2].split()[:2] == ["mirrored", "+0.0022"] and lines[2].endswith("agree: yes")
    with pytest.raises(ValueError, match="at least one reading"):
        format_readings({})


# --- the figures' helpers ----------------------------------------------------------------


def test_period_average_removes_the_gait_oscillation_and_keeps_the_offset():
    from jaxworm.plot import period_average, period_envelope

    t = np.linspace(0.0, 5.0, 501)  # 50 samples per period of 0.5 s
    y = 0.3 + np.sin(2 * np.pi * t / 0.5) + 0.1 * np.cos(2 * np.pi * 3 * t / 0.5)
    tm, ym = period_average(t, y, 0.5)
    np.testing.assert_allclose(ym, 0.3, atol=1e-12)
    assert tm[0] == pytest.approx(0.245) and tm[-1] == pytest.approx(4.755)  # centres
    edges, low, high = period_envelope(t, y, 0.5)
    np.testing.assert_allclose(edges, np.arange(11) * 0.5)
    assert np.all(low < -0.6) and np.all(high > 1.2) and np.all(high < 1.41)
    y[7] = np.nan  # a non-finite sample: NaN windows, left out of the envelope
    tm, ym = period_average(t, y, 0.5)
    assert np.isnan(ym[0]) and np.isfinite(ym[8:]).all()
    assert np.isfinite(period_envelope(t, y, 0.5)[1]).all()
    # Samples over less than one period hold no whole window (a part-period mean was
    # returned as one).
    short = np.linspace(0.0, 1.0, 101)
    assert [a.size for a in period_average(short, np.sin(short), 5.0)] == [0, 0]
    assert period_average(short[:100], np.ones(100), 1.0)[1].tolist() == [1.0]  # just one
    # Uneven times: a window of n samples is not one period, so it is refused (it was
    # averaged over the wrong span); plot_fig2 then draws the raw samples.
    uneven = np.concatenate([np.linspace(0.0, 0.1, 80), np.linspace(0.11, 5.0, 421)])
    with pytest.raises(ValueError, match="evenly spaced, increasing times"):
        period_average(uneven, y, 0.5)
    from jaxworm._plot import _fits_periods

    assert _fits_periods(t, 0.5) and not _fits_periods(uneven, 0.5)
    for bad in (0.0, -0.5, np.nan):
        with pytest.raises(ValueError, match="period = .* is out of range"):
            period_average(t, y, bad)
        with pytest.raises(ValueError, match="period = .* is out of range"):
            period_envelope(t, y, bad)


def test_fig3_panels_share_one_colour_scale_and_check_their_options(tmp_path):
    from matplotlib.image import imread

    from jaxworm.plot import plot_fig3, plot_fig3_panels

    slow = _made_up_sweep(np.full((3, 3), 0.001))
    fast = _made_up_sweep(np.full((3, 3), 0.01))
    alone = imread(plot_fig3(slow, tmp_path / "alone.png"))[..., :3]
    pair = imread(plot_fig3_panels([slow, fast], tmp_path / "pair.png", titles=["a", "b"]))
    pair = pair[..., :3]

    def count(img, rgb):  # pixels of one colour of the RdBu_r map
        return int(np.all(np.abs(img - rgb) < 0.02, axis=-1).sum())

    dark, pale = (0.404, 0.0, 0.122), (0.980, 0.915, 0.876)  # +lim; +lim/10 on a ±lim scale
    # Alone, 0.001 m/s is the top of its own scale; beside 0.01 m/s it is a tenth of it.
    assert count(alone, dark) > 20000 and count(alone, pale) < 1000
    assert count(pair, pale) > 20000 and count(pair, dark) > 20000
    assert pair.shape[1] > 1.8 * alone.shape[1]
    with pytest.raises(ValueError, match="option titles has 1 entries"):
        plot_fig3_panels([slow, fast], tmp_path / "x.png", titles=["a"])


def test_fig2_rows_stacks_runs_and_checks_its_option(tmp_path):
    import jax.numpy as jnp
    from matplotlib.image import imread

    import jaxworm as jw
    from jaxworm.plot import plot_fig2, plot_fig2_rows

    p = jw.Params()
    r = jw.simulate(p, 0.2, ts=jnp.linspace(0.0, 0.2, 5))  # the fig2 command's program
    one = imread(plot_fig2(r, p, tmp_path / "one.png", dpi=50))
    two = imread(plot_fig2_rows([(r, p, "a"), (r, p, "b")], tmp_path / "two.png", dpi=50))
    assert two.shape[0] == 2 * one.shape[0] and two.shape[1] == one.shape[1]
    with pytest.raises(ValueError, match="option average = 'yes'"):
        plot_fig2(r, p, tmp_path / "x.png", average="yes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="at least one run"):
        plot_fig2_rows([], tmp_path / "x.png")


def test_paper_runs_both_readings_side_by_side(tmp_path, capsys):
    code, out, err = run(capsys, "paper", *SHORT, "--size", "2", "--quiet", "--out", str(tmp_path))
    assert code == 0, err
    names = sorted(f.name for f in tmp_path.iterdir())
    assert names == ["fig2.png", "fig3.png", "fig3_2x2.npz", "fig3_2x2_mirrored.npz"]
    assert "MODEL.md reading" in out and "mirrored reading" in out
    assert out.count("    MODEL.md  ") == out.count("    mirrored  ") == 6
