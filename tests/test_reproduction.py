"""Reproducing the paper: `jaxworm fig2`, `jaxworm animate`, `jaxworm paper` and the
comparison with the paper's numbers (`jaxworm._reproduction`), and the frame geometry of
the animation (`jaxworm._animate`).

One compiled solve in all: `fig2` and `animate` both run t1 = 0.2 s with 5 dense times,
so the second reuses the first's program. The comparison is checked on a made-up sweep;
the commands' usage errors are in test_cli.py.
"""

import math

import numpy as np
import pytest

from jaxworm._animate import frame_geometry
from jaxworm._cli import main
from jaxworm._reproduction import (
    PAPER,
    compare_with_paper,
    format_comparison,
    mirror_sweep,
    paper_grid,
    zero_crossing,
)

SHORT = ["--set", "t1=0.2"]


@pytest.fixture(scope="module", autouse=True)
def cache_dir(tmp_path_factory):
    """A private persistent-compilation-cache folder for this module's runs."""
    mp = pytest.MonkeyPatch()
    mp.setenv("JAXWORM_CACHE_DIR", str(tmp_path_factory.mktemp("jax_cache")))
    yield
    mp.undo()


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# --- the commands ------------------------------------------------------------------------


def test_fig2_writes_a_pdf_on_request_and_exits_0(tmp_path, capsys):
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
        "header": {"axes": ["omega", "delta"], "t1": 60.0},
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
