"""Sweeps: every scene equals its own simulation, chunks are saved, a rerun resumes."""

import jax
import numpy as np
import pytest

import jaxworm as jw

# Fixed steps: vmapped and single runs then take the same steps, so they must agree to
# rounding (adaptive steps could differ by a rounding-triggered rejection). Not coarser:
# at dt = 1e-3 s the fixed-step map is ill-conditioned (rounding differences between the
# batched and the single LU grew to 0.4 % in 0.2 s, at 3e-4 s to 2e-4 for ω = 5π); at
# 1e-4 s they stay ~1e-13.
FIXED = jw.Numerics(solver="Rodas4", dt=1e-4)
T1 = 0.2
GRID = {"omega": [3 * np.pi, 5 * np.pi], "delta": [-np.pi / 4, np.pi / 6, np.pi / 3]}


def _single(omega, delta):
    return jw.simulate(jw.Params().replace(omega=omega, delta=delta), T1, FIXED)


def test_every_scene_of_a_sweep_equals_its_own_simulation_in_grid_order():
    s = jw.sweep(GRID, t1=T1, numerics=FIXED, chunk=4, progress=False)  # 6 scenes: padding
    assert s["mean_velocity"].shape == (2, 3) and s["done"].all()
    for i, w in enumerate(GRID["omega"]):
        for j, d in enumerate(GRID["delta"]):
            r = _single(w, d)
            np.testing.assert_allclose(s["mean_velocity"][i, j], float(r.mean_velocity), rtol=1e-9)
            assert s["n_cracks"][i, j] == int(r.n_cracks)
            assert s["status"][i, j] == int(r.status)


def test_chunks_spread_over_devices_give_the_same_sweep():
    # Two "devices" (the same one twice), a worker on each by default (cores shared):
    # the default chunk splits the 6 scenes evenly between the workers.
    one = jw.sweep(GRID, t1=T1, numerics=FIXED, chunk=4, progress=False)
    two = jw.sweep(GRID, t1=T1, numerics=FIXED, progress=False, devices=[jax.devices()[0]] * 2)
    np.testing.assert_allclose(two["mean_velocity"], one["mean_velocity"], rtol=1e-9)
    np.testing.assert_array_equal(two["n_cracks"], one["n_cracks"])
    assert two["done"].all()


def test_workers_on_one_device_each_solve_chunks_and_give_the_same_sweep(monkeypatch):
    # Three threads on one device, chunks of one scene: every worker solves a chunk (the
    # first dispatch alone compiles), and the result is bit-identical to one worker's.
    import threading

    from jaxworm import _sweep

    one = jw.sweep(GRID, t1=T1, numerics=FIXED, chunk=1, progress=False, workers=1)
    threads = []
    run_chunk = _sweep._run_chunk
    two_at_once = threading.Barrier(2, timeout=60)  # broken unless 2 dispatch together

    def recording(*args):
        threads.append(threading.current_thread().name)
        if len(threads) in (2, 3):  # after the first dispatch (compiled under its lock)
            two_at_once.wait()
        return run_chunk(*args)

    monkeypatch.setattr(_sweep, "_run_chunk", recording)
    three = jw.sweep(GRID, t1=T1, numerics=FIXED, chunk=1, progress=False, workers=3)
    assert len(threads) == 6 and len(set(threads)) >= 2, threads
    assert all(n.startswith("jaxworm-sweep") for n in threads), threads  # not the caller
    for name in jw.SWEEP_FIELDS:
        np.testing.assert_array_equal(three[name], one[name])


def test_an_error_in_a_worker_reaches_the_caller_and_finished_chunks_are_kept(
    tmp_path, monkeypatch
):
    from jaxworm import _sweep

    calls = []

    def failing(base, names, values, t1, numerics, horizon="t1"):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("chunk 2 failed")
        return {n: np.zeros(len(values)) for n in jw.SWEEP_FIELDS}

    monkeypatch.setattr(_sweep, "_run_chunk", failing)
    path = tmp_path / "s.npz"
    with pytest.raises(RuntimeError, match="chunk 2 failed"):
        jw.sweep(GRID, t1=T1, chunk=1, path=path, progress=False, workers=2)
    # every chunk that succeeded, in flight when the other failed or not, is saved
    assert int(jw.load_sweep(path)["done"].sum()) == len(calls) - 1


def test_sweep_file_is_self_describing_and_a_rerun_resumes_only_missing_scenes(tmp_path):
    path = tmp_path / "s.npz"
    full = jw.sweep(GRID, t1=T1, numerics=FIXED, chunk=2, path=path, progress=False)
    saved = jw.load_sweep(path)
    assert saved["header"]["axes"] == ["omega", "delta"]
    assert saved["header"]["units"]["mean_velocity"] == "m/s"
    assert saved["header"]["t1"] == T1 and saved["header"]["numerics"]["solver"] == "Rodas4"
    np.testing.assert_array_equal(saved["mean_velocity"], full["mean_velocity"])
    # One type, whether run or read back: fields as attributes, and as a mapping.
    assert isinstance(full, jw.SweepResult) and isinstance(saved, jw.SweepResult)
    keys = ["header", "done", "coords", *jw.SWEEP_FIELDS]
    assert list(saved) == list(full) == keys and len(saved) == len(keys)
    assert "mean_velocity" in saved and "velocity" not in saved
    for n in keys[1:]:
        assert saved[n] is getattr(saved, n)
        if n != "coords":
            np.testing.assert_array_equal(getattr(saved, n), getattr(full, n))
    assert saved.axes == ["omega", "delta"] and saved.shape == (2, 3)
    assert {k: v for k, v in saved.items()}.keys() == dict(saved).keys()
    with pytest.raises(KeyError):
        saved["velocity"]
    # Simulate an interruption: forget two scenes, and poison the rest so that a rerun
    # that recomputed them would show.
    # Written as jaxworm writes it (`_files.save`, with its checksum): an edit by other
    # tools would be refused as damaged.
    from jaxworm import _files

    header, data = _files.load(path, "sweep")
    data["done"][1, :2] = False
    data["result_mean_velocity"][1, :2] = np.nan
    data["result_mean_velocity"][0, :] = 123.0
    _files.save(path, header, data)
    resumed = jw.sweep(GRID, t1=T1, numerics=FIXED, chunk=2, path=path, progress=False)
    assert np.all(resumed["mean_velocity"][0] == 123.0)  # kept, not recomputed
    np.testing.assert_allclose(
        resumed["mean_velocity"][1, :2], full["mean_velocity"][1, :2], rtol=1e-9
    )
    assert jw.load_sweep(path)["done"].all()


def test_a_file_from_another_sweep_is_refused_not_overwritten(tmp_path):
    path = tmp_path / "s.npz"
    jw.sweep({"omega": [4 * np.pi]}, t1=T1, numerics=FIXED, path=path, progress=False)
    before = path.read_bytes()
    with pytest.raises(jw.ResultFileError, match=r"different sweep \(t1 differ\)"):
        jw.sweep({"omega": [4 * np.pi]}, t1=0.1, numerics=FIXED, path=path, progress=False)
    assert path.read_bytes() == before


@pytest.mark.parametrize(
    "grid, match",
    [
        ({"omgea": [1.0]}, "omgea"),
        ({"N": [7, 8]}, "N cannot be swept"),
        ({"omega": [1.0, float("nan")]}, "omega"),
        ({"A": [True]}, r"A = \[True\]: need a non-empty 1-D list of finite numbers"),
        ({}, "empty"),
    ],
)
def test_bad_grids_are_named_in_the_error(grid, match):
    with pytest.raises(ValueError, match=match):
        jw.sweep(grid, t1=T1, numerics=FIXED, progress=False)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(numerics="fast"), TypeError, r"option numerics = 'fast' \(str\) is not a Numerics"),
        (dict(base={"omega": 3.0}), TypeError, r"option base = \{'omega': 3.0\} \(dict\)"),
        (dict(chunk=True), TypeError, r"option chunk = True \(bool\) is not an integer"),
        (dict(chunk="2"), TypeError, r"option chunk = '2' \(str\) is not an integer"),
        (dict(chunk=2.5), ValueError, "option chunk = 2.5 is not an integer: need an integer"),
        (dict(chunk=0), ValueError, "option chunk = 0 is out of range: need an integer chunk >= 1"),
        (dict(chunk=np.int64(0)), ValueError, "option chunk = 0 is out of range"),
        (dict(workers=0), ValueError, "option workers = 0 is out of range: need an integer"),
        (dict(workers=1.5), ValueError, "option workers = 1.5 is not an integer"),
    ],
)
def test_bad_options_are_named_with_their_value_and_what_is_allowed(
    kwargs, error, match, monkeypatch
):
    from jaxworm import _sweep

    monkeypatch.setattr(_sweep, "_run_chunk", None)  # refused before any solve
    with pytest.raises(error, match=match):
        jw.sweep(GRID, t1=T1, progress=False, **kwargs)


def test_a_numpy_integer_chunk_is_taken_as_an_int(tmp_path, monkeypatch):
    from jaxworm import _sweep

    def fake_chunk(base, names, values, t1, numerics, horizon="t1"):
        return {n: np.zeros(len(values)) for n in jw.SWEEP_FIELDS}

    monkeypatch.setattr(_sweep, "_run_chunk", fake_chunk)
    s = jw.sweep(GRID, t1=T1, chunk=np.int64(4), path=tmp_path / "s.npz", progress=False)
    assert s.header["chunk"] == 4 and type(s.header["chunk"]) is int
    assert jw.load_sweep(tmp_path / "s.npz").header["chunk"] == 4


def _fig3_sweep(omega, delta, mean_velocity, status):
    """A sweep's fields as plot_fig3 reads them, over (omega, delta)."""
    return {
        "header": {"axes": ["omega", "delta"], "units": {}, "t1": 1.0},
        "coords": {"omega": np.asarray(omega), "delta": np.asarray(delta)},
        "mean_velocity": np.asarray(mean_velocity),
        "status": np.asarray(status),
    }


def test_fig3_greys_out_scenes_that_did_not_end_ok(tmp_path):
    from matplotlib.image import imread

    from jaxworm._plot import plot_fig3

    omega, delta = np.array([3.0, 4.0]) * np.pi, np.array([0.2, 0.3]) * np.pi
    s = _fig3_sweep(omega, delta, np.zeros((2, 2)), [[0, 7], [0, 0]])
    img = imread(plot_fig3(s, tmp_path / "f.png"))[..., :3]
    grey = np.all(np.abs(img - 0.6) < 0.02, axis=-1)  # the failed cell's fill
    assert grey.sum() > 100


def test_fig3_of_an_unfinished_sweep_leaves_the_unsolved_scenes_blank_and_says_so(tmp_path):
    # Unsolved scenes (status NaN in the file) were drawn grey with a cross, as failed
    # runs, and nothing said the sweep was unfinished.
    from matplotlib.image import imread

    from jaxworm._plot import plot_fig3, solved_note

    omega, delta = np.array([3.0, 4.0]) * np.pi, np.array([0.2, 0.3]) * np.pi
    s = _fig3_sweep(omega, delta, [[0.01, np.nan], [-0.01, 0.01]], [[0, np.nan], [0, 0]])

    def grey_pixels(sweep, name):
        img = imread(plot_fig3(sweep, tmp_path / name))[..., :3]
        return int(np.all(np.abs(img - 0.6) < 0.02, axis=-1).sum())

    failed = grey_pixels(s, "failed.png")  # no done mask: a finished sweep, one failed
    s["done"] = np.array([[True, False], [True, True]])
    unsolved = grey_pixels(s, "unsolved.png")
    assert failed > 20_000 and unsolved < 2_000, (failed, unsolved)  # (text antialiasing)
    assert solved_note(s) == " (3 of 4 scenes solved)"
    s["done"][:] = True
    assert solved_note(s) == ""


def test_fig3_draws_the_cells_of_an_axis_with_one_value(tmp_path):
    # An axis of one value has no spacing to infer a cell from: it was drawn empty.
    from matplotlib.image import imread

    from jaxworm._plot import plot_fig3

    s = _fig3_sweep([4.0 * np.pi], [-0.5, 0.5], [[0.01, -0.01]], [[0, 0]])
    img = imread(plot_fig3(s, tmp_path / "f.png"))[..., :3]
    red = img[..., 0] > img[..., 2] + 0.2  # the +0.01 m/s cell (RdBu_r's top), colour bar
    blue = img[..., 2] > img[..., 0] + 0.2
    assert red.sum() > 50_000 and blue.sum() > 50_000, (red.sum(), blue.sum())


def test_fig3_names_a_mark_without_a_value_for_each_axis(tmp_path):
    from jaxworm._plot import plot_fig3

    s = _fig3_sweep([3.0, 4.0], [0.2, 0.3], np.zeros((2, 2)), np.zeros((2, 2), dtype=int))
    with pytest.raises(ValueError, match="option mark = .*'omega' and 'delta'"):
        plot_fig3(s, tmp_path / "g.png", mark={"A": 1.0})  # was a bare KeyError


def test_a_whole_period_sweep_simulates_each_scene_to_its_last_whole_period(tmp_path):
    grid = {"omega": [4 * np.pi, 5 * np.pi]}  # periods 0.5 s and 0.4 s
    path = tmp_path / "s.npz"
    s = jw.sweep(grid, t1=0.7, numerics=FIXED, path=path, progress=False, horizon="whole_periods")
    assert s["header"]["horizon"] == "whole_periods"
    for i, (w, period) in enumerate(zip(grid["omega"], (0.5, 0.4))):
        r = jw.simulate(jw.Params().replace(omega=w), period, FIXED)
        np.testing.assert_allclose(s["mean_velocity"][i], float(r.mean_velocity), rtol=1e-9)
    with pytest.raises(jw.ResultFileError, match="different sweep"):  # same grid, t1; other horizon
        jw.sweep(grid, t1=0.7, numerics=FIXED, path=path, progress=False)
    with pytest.raises(ValueError, match="option horizon = 'cycles'"):
        jw.sweep(grid, t1=0.7, numerics=FIXED, progress=False, horizon="cycles")


def test_a_sweep_killed_between_chunks_resumes_bit_identical_to_an_uninterrupted_one(
    tmp_path, monkeypatch
):
    # Real solves, cut as in the resume test above (one compiled program). A kill is
    # played by the second save raising: the first chunk saved is on disk, the other lost.
    from jaxworm import _files

    grid = {"omega": GRID["omega"], "delta": GRID["delta"][:2]}
    jw.sweep(grid, t1=T1, numerics=FIXED, chunk=2, path=tmp_path / "whole.npz", progress=False)
    real_save, saves = _files.save, []

    def killed_at_the_second_save(*args, **kwargs):
        if saves:
            raise KeyboardInterrupt
        saves.append(1)
        real_save(*args, **kwargs)

    monkeypatch.setattr(_files, "save", killed_at_the_second_save)
    with pytest.raises(KeyboardInterrupt):
        jw.sweep(grid, t1=T1, numerics=FIXED, chunk=2, path=tmp_path / "s.npz", progress=False)
    monkeypatch.setattr(_files, "save", real_save)
    # one chunk saved, the first to finish (the workers run both at once)
    done = jw.load_sweep(tmp_path / "s.npz")["done"].ravel().tolist()
    assert done in ([True, True, False, False], [False, False, True, True]), done
    jw.sweep(grid, t1=T1, numerics=FIXED, path=tmp_path / "s.npz", progress=False)  # its chunks
    assert (tmp_path / "s.npz").read_bytes() == (tmp_path / "whole.npz").read_bytes()


def test_the_header_names_every_model_option_and_a_file_of_another_reading_is_refused(tmp_path):
    from jaxworm import _files

    path = tmp_path / "s.npz"
    grid = {"omega": [4 * np.pi]}
    jw.sweep(grid, t1=T1, numerics=FIXED, path=path, progress=False)
    header = jw.load_sweep(path)["header"]
    assert header["model_options"] == jw.Params().options()
    tail = jw.Params().replace(friction_forward="tail")
    with pytest.raises(jw.ResultFileError, match=r"model_options differ"):
        jw.sweep(grid, base=tail, t1=T1, numerics=FIXED, path=path, progress=False)
    # a file written before the newer options existed ran their defaults: it resumes
    header, data = _files.load(path, "sweep")
    header["model_options"] = {"wedge": "given", "offset": "rest", "exact": False}
    data["done"][:] = False
    _files.save(path, header, data)
    resumed = jw.sweep(grid, t1=T1, numerics=FIXED, path=path, progress=False)
    assert resumed["done"].all()
    with pytest.raises(jw.ResultFileError, match=r"model_options differ"):
        jw.sweep(grid, base=tail, t1=T1, numerics=FIXED, path=path, progress=False)


def test_a_grid_of_more_than_max_scenes_is_refused_before_anything_is_allocated(
    tmp_path, monkeypatch
):
    import tracemalloc

    from jaxworm import _sweep

    monkeypatch.setattr(_sweep, "_run_chunk", None)  # refused before any solve
    grid = {  # 101 x 100 x 100 = 1 010 000 scenes, each axis short
        "omega": np.linspace(3 * np.pi, 5 * np.pi, 101),
        "delta": np.linspace(np.pi / 6, np.pi / 3, 100),
        "A": np.linspace(0.01, 0.03, 100),
    }
    path = tmp_path / "huge.npz"
    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as e:
            jw.sweep(grid, t1=T1, path=path, progress=False)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    message = str(e.value)
    assert "omega 101 x delta 100 x A 100" in message and "1010000 scenes" in message
    assert f"limit of {_sweep.MAX_SCENES}" in message and _sweep.MAX_SCENES == 10**6
    assert peak < 4_000_000, peak  # one result array alone would take 8 MB
    assert list(tmp_path.iterdir()) == []
    at_limit = {"omega": grid["omega"][:100], "delta": grid["delta"], "A": grid["A"]}
    assert _sweep._check_grid(at_limit).keys() == at_limit.keys()  # 10**6 scenes: accepted


def test_fig3_draws_each_scene_at_its_own_coordinates_whatever_the_grid_order(
    tmp_path, monkeypatch
):
    from matplotlib.figure import Figure

    from jaxworm._plot import plot_fig3

    figures = []
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: figures.append(self))
    omega = np.array([5.0, 3.0, 4.0])  # in units of pi, as drawn; not sorted
    delta = np.array([1 / 3, 1 / 6])
    v = np.array([[1.0, -2.0], [3.0, -4.0], [5.0, -6.0]])  # v[i, j] at omega[i], delta[j]
    s = {
        "header": {"axes": ["omega", "delta"], "units": {}, "t1": 1.0},
        "coords": {"omega": omega * np.pi, "delta": delta * np.pi},
        "mean_velocity": v,
        "status": np.array([[0, 0], [0, 0], [0, 3]]),  # (4 pi, pi/6) failed: not drawn
    }
    plot_fig3(s, tmp_path / "f.png")
    mesh = figures[0].axes[0].collections[0]
    edges = mesh.get_coordinates()  # (ny + 1, nx + 1, 2) cell corners
    x_edges, y_edges = edges[0, :, 0], edges[:, 0, 1]
    assert np.all(np.diff(x_edges) > 0) and np.all(np.diff(y_edges) > 0)
    drawn = np.ma.filled(mesh.get_array(), np.nan).reshape(len(y_edges) - 1, len(x_edges) - 1)
    assert drawn.shape == (2, 3)  # every column drawn
    for i, w in enumerate(omega):
        for j, d in enumerate(delta):
            ix = np.searchsorted(x_edges, w) - 1
            iy = np.searchsorted(y_edges, d) - 1
            want = np.nan if s["status"][i, j] else v[i, j]
            np.testing.assert_equal(drawn[iy, ix], want, err_msg=f"omega {w} pi, delta {d} pi")


def test_one_compiled_program_serves_every_horizon():
    # t1 is an input of the chunk's program: a sweep over another horizon traces and
    # compiles nothing new (a chunk of 5 is a shape no other test of this file uses).
    events = []

    def listener(name, secs, **kwargs):
        if "compile" in name:
            events.append(name)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        first = jw.sweep(GRID, t1=0.05, chunk=5, progress=False)
        assert events, "the first sweep should have traced its program"
        seen = len(events)
        second = jw.sweep(GRID, t1=0.1, chunk=5, progress=False)
        assert events[seen:] == []
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert first["done"].all() and second["done"].all()
    r = jw.simulate(jw.Params().replace(omega=GRID["omega"][1], delta=GRID["delta"][2]), 0.1)
    np.testing.assert_allclose(second["mean_velocity"][1, 2], float(r.mean_velocity), rtol=1e-2)
