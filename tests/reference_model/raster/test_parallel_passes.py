"""The chunked parallel passes of the numba rasterizer give the serial result for any chunk count,
and one call sizes numba's, torch's and BLAS's thread pools together."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("numba")


@pytest.mark.parametrize("n_chunks", [1, 2, 3, 7])
def test_the_chunked_radix_sort_is_the_stable_sort_whatever_the_chunk_count(n_chunks: int) -> None:
    from wcbench.reference_model.raster.kernels import _radix_sort

    rng = np.random.default_rng(n_chunks)
    depths = np.concatenate([rng.uniform(0.01, 80.0, 5000), np.full(300, 7.0), [3.4e38, 0.01]]).astype(np.float32)
    depths = rng.permutation(depths)
    payload = rng.permutation(10 * len(depths))[: len(depths)].astype(np.int64)  # any int64 rides along
    bits = depths.view(np.uint32)
    got = _radix_sort(bits.copy(), payload.copy(), n_chunks)
    np.testing.assert_array_equal(got, payload[np.argsort(bits, kind="stable")])


@pytest.mark.parametrize("n_chunks", [1, 2, 5])
def test_the_visible_set_and_cull_counts_match_numpy(n_chunks: int) -> None:
    from wcbench.reference_model.raster.kernels import _visible_keys

    rng = np.random.default_rng(0)
    reason = rng.choice(np.int8([0, 0, 0, 1, 2, 3, 4, 5]), 4099).astype(np.int8)
    depth = rng.uniform(0.1, 50.0, len(reason)).astype(np.float32)
    vis, bits, counts = _visible_keys(reason, depth, n_chunks)
    expected = np.flatnonzero(reason == 0)
    np.testing.assert_array_equal(vis, expected)
    np.testing.assert_array_equal(bits, depth[expected].view(np.uint32))
    np.testing.assert_array_equal(counts, np.bincount(reason, minlength=6))


def test_set_threads_sizes_numba_torch_and_blas_together_and_the_block_restores_them() -> None:
    from wcbench.reference_model.raster.threads import get_threads, max_threads, set_threads, threads

    before = get_threads()
    try:
        with threads(1) as k:
            assert k == 1
            now = get_threads()
            assert now["numba"] == 1 and now["torch"] == 1 and now["blas"] in (1, None)
        assert get_threads() == before
        assert set_threads(10_000) == max_threads()  # clamped to what numba started with
        with pytest.raises(ValueError):
            set_threads(0)
    finally:
        set_threads(int(before["numba"] or 1))
        torch.set_num_threads(int(before["torch"] or 1))


def test_tile_offsets_are_the_prefix_sums_of_the_chunk_histograms() -> None:
    from wcbench.reference_model.raster.kernels import _tile_offsets

    counts = np.random.default_rng(1).integers(0, 5, (6, 37)).astype(np.int64)
    tile_start, cursor0, chunk_base = _tile_offsets(counts)
    np.testing.assert_array_equal(tile_start, np.concatenate([[0], np.cumsum(counts.sum(0))]))
    np.testing.assert_array_equal(cursor0, tile_start[:-1][None, :] + np.cumsum(counts, 0) - counts)
    np.testing.assert_array_equal(chunk_base, np.cumsum(counts.sum(1)) - counts.sum(1))


def test_the_scratch_pool_reuses_big_arrays_and_never_hands_out_one_twice() -> None:
    from wcbench.reference_model.raster.kernels import _ScratchPool

    pool = _ScratchPool(1 << 10, 1 << 22)
    mine: list[np.ndarray] = []
    a = pool.take((300, 16), np.float32, mine)
    small = pool.take((10,), np.float64, mine)  # below min_bytes: a plain array, not pooled
    assert a.flags.c_contiguous and a.ctypes.data % 64 == 0 and len(mine) == 1 and small.shape == (10,)
    b = pool.take((300, 16), np.float32, mine)  # a is in use: fresh storage
    assert not np.shares_memory(a, b)
    pool.give(mine)
    assert mine == []
    again: list[np.ndarray] = []
    c = pool.take((200, 16), np.float64, again)  # 25.6 kB fits in a returned 19.3 kB block? no: fresh
    d = pool.take((250, 16), np.float32, again)  # fits in one of the two 19.3 kB blocks: reused
    assert not np.shares_memory(c, d) and len(again) == 2
    assert any(np.shares_memory(d, x) for x in (a, b))
    big = pool.take((1 << 21,), np.float32, again)  # 8 MB, beyond max_bytes once given back
    pool.give(again)
    assert sum(x.nbytes for x in pool._free) <= 1 << 22 and not any(np.shares_memory(big, x) for x in pool._free)


@pytest.mark.parametrize("n_channels", [1, 3, 4, 15, 16])
def test_written_out_color_terms_equal_their_plain_loops(n_channels: int) -> None:
    """The kernels' per-channel color terms (a chain of inline functions per count) against the
    plain Python loops of the same functions, bit for bit."""
    from numba import njit
    from numba.np.unsafe.ndarray import to_fixed_tuple

    from wcbench.reference_model.raster import kernels as k

    rng = np.random.default_rng(n_channels)
    planes = k._UGC // (k.TS * k.TS) + n_channels
    buf = rng.random(planes * k.TS * k.TS)
    colors = rng.random(n_channels).astype(np.float32)
    u, w = 37, 0.3125

    @njit
    def jitted(buf: np.ndarray, colors: np.ndarray, u: np.uint64, w: float) -> float:
        cols = to_fixed_tuple(colors, n_channels)
        k._add_colors(buf, u, w, cols)
        return k._dot_colors(buf, u, cols, 0.5)

    fast, plain = buf.copy(), buf.copy()
    got = jitted(fast, colors, np.uint64(u), w)
    cols = tuple(colors)
    k._add_colors(plain, u, w, cols)
    assert got == k._dot_colors(plain, u, cols, 0.5)
    np.testing.assert_array_equal(fast, plain)
