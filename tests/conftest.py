"""Shared test settings and fixtures.

Importing jaxworm enables float64; the assertion below guards every test against a
silent fall-back to float32 (MODEL.md: float32 loses the friction forces).
"""

import os

# The tests leave the user's jaxworm cache alone and do not depend on what it holds:
# program caching is off unless a test turns it on (tests/test_cache.py, the CLI tests).
os.environ.setdefault("JAXWORM_CACHE_DIR", "")

import shutil  # noqa: E402
import tempfile  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import pytest  # noqa: E402

# JAX's compilation cache, shared by this run's workers and fresh for each run: tests
# that build the same program (another closure of the same solve, or the same program in
# the other worker) compile it once. It caches XLA's compiled code keyed on the traced
# program, so every test still traces its own code (monkeypatched internals included).
# The first process (xdist's controller, or the only one) makes the folder before the
# workers start, and they inherit it; it is removed when the run ends.
# JAXWORM_TEST_XLA_CACHE="" turns it off; a folder given there is kept.
_made_xla_cache = None
if "JAXWORM_TEST_XLA_CACHE" not in os.environ and "PYTEST_XDIST_WORKER" not in os.environ:
    _made_xla_cache = tempfile.mkdtemp(prefix="jaxworm-tests-")
    os.environ["JAXWORM_TEST_XLA_CACHE"] = _made_xla_cache
_xla_cache = os.environ.get("JAXWORM_TEST_XLA_CACHE", "")
if _xla_cache:
    jax.config.update("jax_compilation_cache_dir", _xla_cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

import jaxworm  # noqa: F401, E402  (enables x64)

#: Test files whose tests take longest (compilations mostly; `pytest --durations`), run
#: first: `--dist loadfile` hands files to the two workers in collection order, so the
#: longest ones start at once and the short ones fill the end, where a long file
#: collected late kept one worker busy while the other idled.
LONGEST_FIRST = (
    "test_sensitivity.py",
    "test_gradients.py",
    "test_reference.py",
    "test_notebooks.py",
    "test_train.py",
    "test_rosenbrock.py",
    "test_soil.py",
    "test_feedback.py",
)


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: file order kept


def pytest_sessionfinish(session, exitstatus):
    if _made_xla_cache and not hasattr(session.config, "workerinput"):
        shutil.rmtree(_made_xla_cache, ignore_errors=True)


@pytest.fixture(autouse=True, scope="session")
def _float64_enabled():
    assert jnp.zeros(()).dtype == jnp.float64, "jaxworm must enable float64 on import"


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    """A private jaxworm cache folder (`JAXWORM_CACHE_DIR`) for one test module's runs:
    programs compiled by one test are reused by the next, and the user's cache is left
    alone."""
    path = tmp_path_factory.mktemp("jax_cache")
    mp = pytest.MonkeyPatch()
    mp.setenv("JAXWORM_CACHE_DIR", str(path))
    # jaxworm keeps a compilation cache folder that JAX already has (the run's, above):
    # set it aside, so that compiled programs land in this folder's jax/ as a user's do.
    saved = {k: jax.config.values[k] for k in _COMPILATION_CACHE_OPTIONS}
    _use_compilation_cache(None)
    yield path
    mp.undo()
    _use_compilation_cache(saved.pop("jax_compilation_cache_dir"))
    for k, v in saved.items():  # the thresholds the CLI changes
        jax.config.update(k, v)


_COMPILATION_CACHE_OPTIONS = (
    "jax_compilation_cache_dir",
    "jax_persistent_cache_min_compile_time_secs",
    "jax_persistent_cache_min_entry_size_bytes",
)


def _use_compilation_cache(folder):
    from jax.experimental.compilation_cache import compilation_cache

    jax.config.update("jax_compilation_cache_dir", folder)
    compilation_cache.reset_cache()


# --- one shared, compiled simulation batch -------------------------------------------
#
# A simulate() compile costs ~20 s on a small CPU, so every test that needs a solve
# reads from this single vmapped batch (t1 = 0.1 s). The lanes use a custom controller
# with a constant rate u_k = rate for all segments, no friction (mu_s = 0) and a
# negligible back pressure (Wg = 1e-30), so the only forces are the springs:
#   lane 0: rate 0      -> the worm must stay exactly at rest
#   lane 1: rate 1e-3   -> l̄ grows linearly, momentum is conserved
#   lane 2: rate 0, lam = 0.5 (traced, invalid: lam >= 1) -> status "invalid_parameters"

import equinox as eqx  # noqa: E402
from jaxtyping import Array, Float  # noqa: E402

import jaxworm as jw  # noqa: E402


class ConstantRate(jw.AbstractController):
    """u_k = rate for every segment (a user-defined controller)."""

    rate: Float[Array, ""]

    def __call__(self, t, x, v, lbar, body):
        return jnp.full(body.N - 1, 1.0) * self.rate


SHARED_T1 = 0.1
FRICTIONLESS = jw.Numerics(solver="Kvaerno5", rtol=1e-6, atol=1e-9, norm="full")
SHARED_RATES = (0.0, 1e-3, 0.0)
SHARED_LAMS = (1.5, 1.5, 0.5)


@pytest.fixture(scope="session")
def constant_rate_runs():
    def one(rate, lam):
        p = jw.Params(gait=ConstantRate(rate)).replace(mu_s=0.0, Wg=1e-30, lam=lam)
        # No friction, so nothing damps the elastic ringing: the default positions norm
        # would damp it numerically (flagged by the energy balance); resolve it instead.
        return jw.simulate(p, SHARED_T1, FRICTIONLESS)

    result = eqx.filter_jit(jax.vmap(one))(jnp.array(SHARED_RATES), jnp.array(SHARED_LAMS))
    return {"result": result, "rates": SHARED_RATES, "lams": SHARED_LAMS, "t1": SHARED_T1}


# --- one compiled batch over every float parameter (validation, fuzz, batch checks) ----
#
# Every float parameter is a batched argument, so a single compiled program serves any
# mix of traced values: `run_flat_batch(rows, t1s)` with `rows` a list of {name: value}
# over `FLAT_BATCH_DEFAULTS` (missing names keep their default) and `t1s` one t1 per row.

FLAT_BATCH_SIZE = 4
#: `simulate`'s default, so that single runs share their compilation with other tests.
FLAT_BATCH_NUMERICS = jw.PRESETS["fast"]
#: Table 1 (crack_gap0 stays None, eq. 13: its traced check is `params_valid`'s).
FLAT_BATCH_DEFAULTS = {
    n: float(v) for n, v in jw.Params().flat().items() if n != "N" and v is not None
}


@pytest.fixture(scope="session")
def run_flat_batch():
    names = tuple(FLAT_BATCH_DEFAULTS)

    @eqx.filter_jit
    def batch(values, t1s):
        def one(vals, t1):
            return jw.simulate(
                jw.Params().replace(**dict(zip(names, vals))), t1, FLAT_BATCH_NUMERICS
            )

        return jax.vmap(one)(values, t1s)

    def run(rows, t1s):
        assert len(rows) == FLAT_BATCH_SIZE == len(t1s)
        values = jnp.array(
            [[row.get(n, FLAT_BATCH_DEFAULTS[n]) for n in names] for row in rows], dtype=jnp.float64
        )
        return batch(values, jnp.asarray(t1s, dtype=jnp.float64))

    return run
