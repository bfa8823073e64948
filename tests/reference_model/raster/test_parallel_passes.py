"""The chunked parallel passes of the numba rasterizer give the serial result for any chunk count,
and one call sizes numba's, torch's and BLAS's thread pools together."""

from __future__ import annotations

from typing import Any

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


@pytest.mark.parametrize("n_chunks", [1, 2, 3, 16])
def test_the_tile_counting_sort_lists_gaussian_indices_front_to_back_whatever_the_chunk_count(n_chunks: int) -> None:
    """``_tile_counts`` + ``_tile_offsets`` + ``_tile_fill`` (chunks handed out alternately from both
    halves, each list's next line prefetched) against a plain Python counting sort: every tile's
    list holds the Gaussian indices in depth order, and ``entry_pos`` each Gaussian's list slots."""
    from wcbench.reference_model.raster import kernels as k

    rng = np.random.default_rng(n_chunks)
    n, tiles_x, tiles_y = 900, 7, 5
    rec = np.zeros((n, k._NPRM), np.float32)
    x0 = rng.integers(0, tiles_x * k.TS, n)
    y0 = rng.integers(0, tiles_y * k.TS, n)
    rec[:, k._BX] = x0
    rec[:, k._BX + 1] = np.minimum(x0 + rng.integers(0, 40, n), tiles_x * k.TS - 1)
    rec[:, k._BX + 2] = y0
    rec[:, k._BX + 3] = np.minimum(y0 + rng.integers(0, 40, n), tiles_y * k.TS - 1)
    order = rng.permutation(n)[: n - 50].astype(np.int64)  # a depth order of the visible ones
    m = len(order)
    counts = np.zeros((n_chunks, tiles_x * tiles_y), np.int64)
    pbox = np.empty((m, 4), np.int32)
    per_g = np.empty(m, np.int64)
    k._tile_counts(order, rec, tiles_x, pbox, counts, per_g)
    tile_start, cursor0, chunk_base = k._tile_offsets(counts)
    e_total = int(tile_start[-1])
    goff = np.empty(m, np.int64)
    tile_ids = np.full(e_total, -1, np.int32)
    entry_pos = np.full(e_total, -1, np.int64)
    k._tile_fill(order, pbox, tiles_x, cursor0, chunk_base, goff, tile_ids, entry_pos)

    lists: list[list[int]] = [[] for _ in range(tiles_x * tiles_y)]
    slots: list[tuple[int, int]] = []  # (tile, place in its list) of each Gaussian-major entry
    for g in order:
        bx = rec[g, k._BX:k._BX + 4].astype(int) // k.TS
        for ty in range(bx[2], bx[3] + 1):
            for tx in range(bx[0], bx[1] + 1):
                slots.append((ty * tiles_x + tx, len(lists[ty * tiles_x + tx])))
                lists[ty * tiles_x + tx].append(int(g))
    for t, ids in enumerate(lists):
        assert tile_ids[tile_start[t]:tile_start[t + 1]].tolist() == ids
    np.testing.assert_array_equal(entry_pos, [tile_start[t] + i for t, i in slots])
    np.testing.assert_array_equal(per_g, np.diff(goff, append=e_total))
    np.testing.assert_array_equal(pbox, rec[order, k._BX:k._BX + 4].astype(np.int32))


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


@pytest.mark.parametrize("n_lanes", [8, 16])
@pytest.mark.parametrize("n_channels", [3, 15])
def test_entry_sums_in_vector_adds_equal_the_plain_fixed_order_sums(n_lanes: int, n_channels: int) -> None:
    """``_entry_sums`` (explicit 8-lane vector adds, :func:`_acc8`) against plain Python loops of the
    documented order (8 column accumulators down the visited rows, lanes j0..j0+7 then j0+8..j0+15,
    then a fixed tree), bit for bit."""
    from wcbench.reference_model.raster import kernels as k

    npx = k.TS * k.TS
    rng = np.random.default_rng(n_lanes + n_channels)
    S = rng.standard_normal(k._UGC + n_channels * npx + (k._NQ + n_channels) * 8) * 10.0 ** rng.integers(
        -8, 8, k._UGC + n_channels * npx + (k._NQ + n_channels) * 8)
    j0 = 0 if n_lanes == k.TS else 5
    gy0, gy1, rows = 2, 13, 0b0010_1101_1011_0100
    out = np.full((3, k._NQ + n_channels), np.nan, np.float32)
    k._entry_sums(S.copy(), rows, gy0, gy1, j0, n_lanes, n_channels, out, 1)

    def plain(plane_of: Any) -> float:
        a = [0.0] * 8
        for r in range(gy0, gy1 + 1):
            if (rows >> r) & 1:
                for h in range(n_lanes // 8):
                    for lane in range(8):
                        a[lane] += plane_of(r * k.TS + j0 + 8 * h + lane)
        return ((a[0] + a[1]) + (a[2] + a[3])) + ((a[4] + a[5]) + (a[6] + a[7]))

    want = [plain(lambda p, q=q: S[(k._BG + q) * npx + p]) for q in range(k._NQ)]
    want += [plain(lambda p, c=c: S[k._BW * npx + p] * S[k._UGC + c * npx + p]) for c in range(n_channels)]
    np.testing.assert_array_equal(out[1], np.array(want, np.float32))
    assert np.isnan(out[0]).all() and np.isnan(out[2]).all()  # only row k is written


def test_the_projection_lane_loop_equals_its_python_body_lane_by_lane() -> None:
    """``_project_lanes`` compiled (one vector loop over 8 Gaussians) against its own body run by
    the Python interpreter, lane by lane, on lanes that hit every cull reason: the vectorized code
    is the per-Gaussian arithmetic, bit for bit."""
    from wcbench.reference_model.raster import kernels as k

    rng = np.random.default_rng(3)
    pl = k._PL
    buf = np.zeros(k._NLF * pl)
    means = rng.uniform(-2, 2, (pl, 3)) + np.array([0.0, 0.0, 6.0])
    means[1, 2] = -1.0  # behind the camera
    quats = rng.standard_normal((pl, 4))
    quats[2] = 0.0  # the identity fallback
    scales = rng.uniform(0.01, 0.5, (pl, 3))
    scales[3] = [1e-30, 1e30, 1.0]  # a needle
    o255 = rng.uniform(0.5, 255.0, pl)
    o255[4] = 0.5  # under ALPHA_MIN
    means[5, 0] = 500.0  # off the image
    o255[6] = 20.0  # faint: box from the log
    fin = np.ones(pl)
    fin[7] = 0.0  # a non-finite input
    for ln in range(pl):
        for q in range(3):
            buf[(k._LPX + q) * pl + ln] = means[ln, q]
            buf[(k._LSX + q) * pl + ln] = scales[ln, q]
        for q in range(4):
            buf[(k._LQW + q) * pl + ln] = quats[ln, q]
    buf[k._LO255 * pl:(k._LO255 + 1) * pl] = o255
    buf[k._LLOG * pl:(k._LLOG + 1) * pl] = np.where(o255 < k._KK_SAT, 2.0 * np.log(o255), 0.0)
    buf[k._LFIN * pl:(k._LFIN + 1) * pl] = fin
    V = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    intr = (200.0, 210.0, 64.0, 48.0)
    args = (V, (0.1, -0.2, 0.3), intr, k._jacobian_clamp(np.array(intr), 128.0, 96.0), 0.01, 1e10, 128.0, 96.0)
    fast, slow = buf.copy(), buf.copy()
    k._project_lanes(fast, *args)
    with np.errstate(all="ignore"):
        k._project_lanes.py_func(slow, *args)
    why = fast[k._LWHY * pl:(k._LWHY + 1) * pl]
    assert sorted(set(why.tolist())) == [0, k.CULL_NONFINITE, k.CULL_NEAR_FAR, k.CULL_TRANSPARENT, k.CULL_OFFSCREEN]
    np.testing.assert_array_equal(fast, slow)
