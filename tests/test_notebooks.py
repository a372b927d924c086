"""The notebooks run top to bottom in their fast mode (`JAXWORM_FAST=1`: short horizon,
tiny grid), executed with nbclient in fresh kernels; outputs are not written back.

The notebooks run at once, each in its own kernel (a process of its own): their time is
mostly XLA compiling, which uses one core each.
"""

import asyncio
import os
from pathlib import Path

import nbclient  # in the `test` extra: a missing one fails here rather than skipping
import nbformat
import numpy as np
import pytest

import jaxworm as jw

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
#: Each notebook and the files its fast mode must leave in JAXWORM_NOTEBOOK_OUT.
FAST_NOTEBOOKS = {
    "01_paper_reproduction.ipynb": ("fig2.png", "worm.gif"),
    "02_gait_optimisation.ipynb": ("grid.npz", "history.npz", "paths.png"),
    "03_closed_loop.ipynb": ("soil.png", "sensors.png", "closed_loop.png", "training.npz"),
}
#: Each notebook's sweep file and the grid shape its fast mode solves.
FAST_SWEEPS = {
    "01_paper_reproduction.ipynb": ("fig3.npz", (2, 2)),
    "02_gait_optimisation.ipynb": ("grid.npz", (5, 5)),
}
#: For a notebook without a sweep: a file of arrays it saves, one array in it and the
#: shape its fast mode gives (for notebook 03, a training speed per step, every step's
#: solves ok).
FAST_ARRAYS = {
    "03_closed_loop.ipynb": ("training.npz", "training_velocity", (3,)),
}
#: Each notebook's horizon in fast mode: at least one period of its slowest gait, for
#: the notebooks that average over whole periods.
FAST_T1 = {
    "01_paper_reproduction.ipynb": 0.5,
    "02_gait_optimisation.ipynb": 0.7,
    "03_closed_loop.ipynb": 0.7,
}


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    """Every notebook of FAST_NOTEBOOKS run in fast mode, concurrently: {name: (the
    executed notebook, its folder)}. The notebooks as committed must have no outputs."""
    runs = {}
    for name in FAST_NOTEBOOKS:
        nb = nbformat.read(NOTEBOOKS / name, as_version=4)
        assert not any(c.get("outputs") for c in nb.cells if c.cell_type == "code"), (
            f"{name} is committed with outputs: clear them"
        )
        folder = tmp_path_factory.mktemp(name.split("_")[0])
        env = {
            **os.environ,
            "JAXWORM_FAST": "1",
            "JAXWORM_NOTEBOOK_OUT": str(folder / "out"),
            "JAXWORM_CACHE_DIR": str(folder / "jax_cache"),
            "MPLBACKEND": "Agg",
        }
        client = nbclient.NotebookClient(
            nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(folder)}}
        )
        runs[name] = (nb, folder, client, env)

    async def all_of_them():
        # A failing cell raises here (CellExecutionError), naming the notebook's error.
        await asyncio.gather(*(c.async_execute(env=env) for _, _, c, env in runs.values()))

    asyncio.run(all_of_them())
    return {name: (nb, folder) for name, (nb, folder, _, _) in runs.items()}


@pytest.mark.parametrize("name", list(FAST_NOTEBOOKS))
def test_notebook_runs_top_to_bottom_in_fast_mode(name, executed):
    nb, folder = executed[name]
    errors = [
        o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"
    ]
    assert not errors, errors
    for produced in FAST_NOTEBOOKS[name]:
        assert (folder / "out" / produced).exists(), produced
    # The notebook read the environment and chose its fast settings: its first code cell
    # says so, and the sweep it saved has the fast grid.
    setup = next(c for c in nb.cells if c.cell_type == "code")
    printed = "".join(o.get("text", "") for o in setup.outputs if o.output_type == "stream")
    assert f"fast mode: True; t1 = {FAST_T1[name]} s" in printed, printed
    if name in FAST_SWEEPS:
        sweep_file, shape = FAST_SWEEPS[name]
        assert jw.load_sweep(folder / "out" / sweep_file)["mean_velocity"].shape == shape
    else:
        file, key, shape = FAST_ARRAYS[name]
        with np.load(folder / "out" / file) as saved:
            assert saved[key].shape == shape, saved[key].shape
            assert np.all(np.isfinite(saved[key])), saved[key]
