"""The particle filters' standard normal draws (:mod:`gpf_nav.filters.normal_draws`): the generator's own
below the row streams' size, each row its stream's own from it, reproducible and independent of the threads,
and standard normal."""
import os
import threading

import numpy as np
import pytest

from gpf_nav.filters import normal_draws
from gpf_nav.filters.normal_draws import ROW_STREAMS, NormalDraws
from gpf_nav.filters.particle import BootstrapPF
from gpf_nav.kernels import PARALLEL
from gpf_nav.models.lunar import LunarDescentModel


def test_a_small_draw_is_the_generators_own():
    draws = NormalDraws(np.random.default_rng(5))
    expected = np.random.default_rng(5)
    for rows, count in ((6, 500), (9, ROW_STREAMS - 1), (3, 1)):
        np.testing.assert_array_equal(draws(rows, count), expected.standard_normal((rows, count)))
    assert draws.rng.random() == expected.random()  # (the generator left as numpy's draw leaves it)


def test_each_row_of_a_large_draw_is_its_streams_own_numpy_draw():
    seed = np.random.default_rng(9).integers(2 ** 63)  # (what the filter's generator gives the row streams)
    children = np.random.SeedSequence(int(seed)).spawn(6)
    z = NormalDraws(np.random.default_rng(9))(6, ROW_STREAMS + 1)
    for row, child in zip(z, children):
        np.testing.assert_array_equal(row, np.random.Generator(np.random.SFC64(child)).standard_normal(row.size))


@pytest.mark.parametrize("workers", (1, 2, 5))
def test_a_large_draw_depends_on_the_seed_and_the_shapes_not_on_the_threads(monkeypatch, workers):
    reference = NormalDraws(np.random.default_rng(11))
    shapes = ((6, ROW_STREAMS), (9, ROW_STREAMS + 3), (6, PARALLEL), (7, PARALLEL + 1))  # (threads from PARALLEL)
    expected = [reference(*shape) for shape in shapes]
    monkeypatch.setattr(normal_draws, "_workers", lambda: workers)
    draws = NormalDraws(np.random.default_rng(11))
    for shape, want in zip(shapes, expected):
        got = draws(*shape)
        assert got.shape == shape
        np.testing.assert_array_equal(got, want)
    other = NormalDraws(np.random.default_rng(12))(*shapes[0])
    assert not np.array_equal(other, expected[0])


def test_the_rows_of_a_large_draw_are_independent_standard_normals():
    count = 50 * ROW_STREAMS
    z = NormalDraws(np.random.default_rng(3))(6, count)
    tolerance = 5.0 / np.sqrt(count)
    np.testing.assert_allclose(z.mean(axis=1), 0.0, atol=tolerance)
    np.testing.assert_allclose(z.std(axis=1), 1.0, atol=tolerance)
    correlation = np.corrcoef(z)
    np.testing.assert_allclose(correlation[~np.eye(6, dtype=bool)], 0.0, atol=tolerance)


def test_the_generator_gives_the_row_streams_one_number_at_the_first_large_draw():
    rng = np.random.default_rng(7)
    draws = NormalDraws(rng)
    first, second = draws(6, ROW_STREAMS), draws(6, ROW_STREAMS)
    assert not np.isin(second, first).any()  # the streams go on
    expected = np.random.default_rng(7)
    expected.integers(2 ** 63)
    assert rng.random() == expected.random()


def test_a_large_bootstrap_filter_is_reproducible_bit_for_bit():
    model = LunarDescentModel()
    mean = np.array([1.838e6, 0.0, 0.0, 0.0, 1.63e3, 0.0])
    cov = np.diag([1e6, 1e6, 1e6, 1.0, 1.0, 1.0])
    y = model.measure(mean[None])[0] + np.array([30.0, 1e-4, -1e-4])
    means = []
    for _ in range(2):
        pf = BootstrapPF(model, ROW_STREAMS + 10, seed=4)
        pf.initialize(mean, cov)
        for _ in range(3):
            pf.predict(10.0)
            pf.update(y)
        means.append(pf.mean)
    np.testing.assert_array_equal(means[0], means[1])


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork only")
def test_a_forked_child_draws_on_a_pool_of_its_own():
    """The parent's pool threads are not in a forked child: its large draws still complete, with the
    parent's numbers for the same seed."""
    expected = NormalDraws(np.random.default_rng(21))(6, PARALLEL)  # (the parent's pool now exists)
    read, write = os.pipe()
    child = os.fork()
    if child == 0:  # pragma: no cover (the child)
        try:
            same = np.array_equal(NormalDraws(np.random.default_rng(21))(6, PARALLEL), expected)
            os.write(write, b"1" if same else b"0")
        finally:
            os._exit(0)
    os.close(write)
    signal = threading.Event()
    answer = []

    def receive():
        answer.append(os.read(read, 1))
        signal.set()

    threading.Thread(target=receive, daemon=True).start()
    finished = signal.wait(30)
    if not finished:
        os.kill(child, 9)
    os.waitpid(child, 0)
    assert finished, "the child's draw did not complete"
    assert answer == [b"1"]
