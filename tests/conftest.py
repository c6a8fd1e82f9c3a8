"""Strict test configuration (house style): x64 available for gradient checks, no silent rank promotion."""

import os

# Several tests shard frames over devices; the host platform must be split before jax initialises. The suite's
# programs are compiled at XLA's backend optimisation level 0: XLA compilation was ~70% of the suite's time (JAX's
# own compile events, 1,513 compiles in six files: 149 s of 213 s), most programs run once or a few times, and level
# 0 leaves the program XLA fuses as it is (the HLO passes) and only skips LLVM's optimisation of the machine code.
# Measured 2026-12-03 on the 2-core CPU: compile-bound files 76 -> 57 s, the run-bound ones (fits, engine passes,
# batch) 149 -> 145 s. And with XLA:CPU's older loop emitters (`--xla_cpu_use_fusion_emitters=false`), which
# compile the same fused program several times faster (measured 2026-12-03 on the same CPU: tests/test_oracle.py
# 157 -> 99 s, the whole suite 1,021 -> 714 s in pytest); where this jaxlib does not know the flag (an unknown flag
# aborts XLA), a child process finds out first and the suite runs without it. Benchmarks, the demo and users run at
# XLA's defaults; set XLA_FLAGS to test at them.
_TEST_XLA_FLAGS = "--xla_force_host_platform_device_count=4 --xla_backend_optimization_level=0"
_FAST_COMPILE = "--xla_cpu_use_fusion_emitters=false"


def _test_xla_flags() -> str:
    import subprocess
    import sys

    flags = f"{_TEST_XLA_FLAGS} {_FAST_COMPILE}"
    try:
        probe = subprocess.run([sys.executable, "-c", "import jax; jax.numpy.zeros(1).block_until_ready()"],
                               env={**os.environ, "XLA_FLAGS": flags}, capture_output=True, timeout=300)
    except (OSError, subprocess.SubprocessError):
        return _TEST_XLA_FLAGS
    return flags if probe.returncode == 0 else _TEST_XLA_FLAGS


if "XLA_FLAGS" not in os.environ:  # set once, in the first process (xdist's workers inherit it)
    os.environ["XLA_FLAGS"] = _test_xla_flags()

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

import atexit
import pathlib
import shutil
import tempfile

import pytest


def _persistent_compilation_cache() -> None:
    """JAX's persistent compilation cache in a fresh folder for this test session (one per xdist worker: JAX writes
    its entries without a lock, so two processes never share a folder), removed at exit. The per-file clearing below
    then empties only memory: a program a later file compiles again (the same pass at the same shapes) is read back
    from disk instead of compiled, on CPU too (jax >= 0.4.26). ``SSS_JAX_TEST_JAX_CACHE=0`` switches it off."""
    if os.environ.get("SSS_JAX_TEST_JAX_CACHE", "1") == "0":
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    folder = tempfile.mkdtemp(prefix=f"sss_jax-tests-jax-cache-{worker}-")
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # the eager ops' small programs too
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


_persistent_compilation_cache()

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared"
if not SHARED.exists():  # CI clones the repo with shared/ beside it; a developer checkout may nest differently
    SHARED = pathlib.Path(__file__).resolve().parents[1].parent / "shared"


# The files that take longest, longest first (the sums of their tests' times, `--durations=0`, 2026-12-07 on the
# 2-core CPU: test_match.py 182 s, test_performance.py 179, test_techniques.py 170 ... test_bad_input.py 37; the
# suite's sum 2,028 s). `--dist loadfile` hands whole files to the workers in the queue's order as each worker frees
# up; xdist's own order (`--loadscope-reorder`, its default) puts the files with the most tests first, so the
# heaviest files, which hold few long tests (test_match.py's 11 fits and checks, test_stability.py's 8 around one
# sweep), came last and one worker ran one of them alone at the end. Longest first (the classic rule for this kind
# of schedule), the last files handed out are short ones. A file not named keeps its place after these; the tests
# within a file keep theirs.
LONGEST_FILES = ("test_match.py", "test_performance.py", "test_techniques.py", "test_oracle.py", "test_fidelity.py",
                 "test_presets.py", "test_batch.py", "test_stability.py", "test_io_cli.py", "test_fitting.py",
                 "test_real_frames.py", "test_engine_passes.py", "test_report_bench.py", "test_montecarlo.py",
                 "test_report.py", "test_slab_transmission.py", "test_engines.py", "test_every_option.py",
                 "test_bad_input.py")


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):  # with pytest-xdist: the order below, not the count of tests
        config.option.loadscopereorder = False


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FILES)))  # stable: each file keeps its order


@pytest.fixture(autouse=True, scope="module")
def _fresh_compilation_caches():
    """Each test file starts from empty JAX caches: the compiled programs of 400 tests held in one process grew the
    run's memory until XLA's compiler crashed late in the suite (it passes alone)."""
    yield
    jax.clear_caches()


@pytest.fixture
def as_users_run_it():
    """The messages a user sees: the test run checks every annotation (``--jaxtyping-packages`` in pyproject.toml),
    which answers bad input before the library's own checks can; tests of those messages switch the checker off."""
    import jaxtyping

    jaxtyping.config.update("jaxtyping_disable", True)
    yield
    jaxtyping.config.update("jaxtyping_disable", False)


@pytest.fixture
def bench_timed_together(monkeypatch) -> list[set[str]]:
    """The names of the functions each ``side_by_side`` call of the bench timed in turn, one set per call: a ratio's
    two sides belong in one call (one after the other, a slow minute of the machine fell on one side only)."""
    import sss_jax._bench as bench

    calls: list[set[str]] = []
    side_by_side = bench.side_by_side

    def spy(fns, **kwargs):
        calls.append(set(fns))
        return side_by_side(fns, **kwargs)

    monkeypatch.setattr(bench, "side_by_side", spy)
    return calls


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    if not SHARED.exists():
        pytest.skip("../shared is not beside the checkout")
    return SHARED


@pytest.hookimpl(optionalhook=True)  # a run without pytest-xdist (-p no:xdist) still collects
def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (the README's test command): one worker per core, as many as memory holds at the suite's peak of
    ~3.4 GB per process (measured with /usr/bin/time -v), so a many-core machine with little memory does not swap."""
    # ``sss_jax._machine.usable_cores``'s rule, not imported: importing the package starts JAX's backend (~2 s) in
    # the xdist controller, which runs no test
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    try:
        memory_gb = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        return cores
    return max(1, min(cores, int(memory_gb // 4)))
