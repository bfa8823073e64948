"""Sem-CS (fwIoU): hand-computed case, brute force, ignore label, batch == accumulated, metric wiring."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from metric_tester import check_metric

from wcbench.metrics.base import MetricContext
from wcbench.metrics.semantic.consistency import (
    SemanticConsistency,
    confusion_matrices,
    confusion_matrix,
    fwiou,
    sem_cs,
)

# float64 sums of at most a few thousand terms: agreement is exact up to rounding
EXACT = 1e-12


def fwiou_bruteforce(l0: np.ndarray, l1: np.ndarray, num_classes: int, ignore: int | None) -> float:
    """docs/design.md §5 word for word, with python loops over classes and pixels."""
    pairs = [
        (int(a), int(b))
        for a, b in zip(l0.ravel(), l1.ravel())
        if ignore is None or (a != ignore and b != ignore)
    ]
    total = len(pairs)
    if total == 0:
        return float("nan")
    out = 0.0
    for c in range(num_classes):
        t_c = sum(1 for a, _ in pairs if a == c)
        if t_c == 0:
            continue
        n_cc = sum(1 for a, b in pairs if a == c and b == c)
        col = sum(1 for _, b in pairs if b == c)
        out += t_c / total * n_cc / (t_c + col - n_cc)
    return out


def test_hand_computed_case():
    # source: 3 pixels of class 0, 1 pixel of class 1; edit moves one class-0 pixel to class 1
    src = np.array([[0, 0], [0, 1]])
    edit = np.array([[0, 0], [1, 1]])
    # class 0: t=3, n00=2, column 0 = 2 -> IoU 2/3; class 1: t=1, n11=1, column 1 = 2 -> IoU 1/2
    expected = 3 / 4 * 2 / 3 + 1 / 4 * 1 / 2  # = 0.625
    assert sem_cs(src, edit, num_classes=2) == pytest.approx(expected, abs=EXACT)
    np.testing.assert_array_equal(confusion_matrix(src, edit, num_classes=2), [[2, 1], [0, 1]])


def test_identical_maps_give_one_and_disjoint_give_zero():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 5, (2, 7, 9))
    assert sem_cs(a, a, num_classes=5) == pytest.approx(1.0, abs=EXACT)
    assert sem_cs(np.zeros((4, 4), int), np.ones((4, 4), int), num_classes=2) == 0.0


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("dtype", [np.uint8, np.int32, np.int64])
def test_against_bruteforce(seed, dtype):
    rng = np.random.default_rng(seed)
    k = int(rng.integers(2, 7))
    l0 = rng.integers(0, k, (9, 11)).astype(dtype)
    l1 = np.where(rng.random((9, 11)) < 0.6, l0, rng.integers(0, k, (9, 11))).astype(dtype)
    ignore = 255 if dtype == np.uint8 else -1
    l0[rng.random((9, 11)) < 0.1] = ignore
    l1[rng.random((9, 11)) < 0.1] = ignore
    got = sem_cs(l0, l1, num_classes=k, ignore_index=ignore)
    assert got == pytest.approx(fwiou_bruteforce(l0, l1, k, ignore), abs=EXACT)


def test_ignore_label_is_excluded_in_both_maps():
    src = np.array([[0, 0, 255], [1, 1, 1]])
    edit = np.array([[0, 255, 1], [1, 1, 0]])
    cm = confusion_matrix(src, edit, num_classes=2, ignore_index=255)
    np.testing.assert_array_equal(cm, [[1, 0], [1, 2]])  # the two pixels touching 255 are dropped
    assert cm.sum() == 4
    with pytest.raises(ValueError, match="label 255 is outside"):
        confusion_matrix(src, edit, num_classes=2, ignore_index=None)


def test_all_ignored_is_nan_and_metric_reports_reason():
    full = np.full((3, 3), 255)
    assert np.isnan(sem_cs(full, full, num_classes=4))
    m = SemanticConsistency(None, num_classes=4)
    m.update(full[None], source=full[None])
    out = m.compute()
    assert out["sem_cs"].value is None and "ignore label" in out["sem_cs"].reason
    assert out["sem_cs"].per_frame == [None]


def test_per_frame_mean_vs_pooled():
    src = np.array([np.zeros((2, 2), int), np.array([[0, 1], [1, 1]])])
    edit = np.array([np.zeros((2, 2), int), np.array([[1, 1], [1, 0]])])
    per = sem_cs(src, edit, num_classes=2, reduction="none")
    assert per[0] == 1.0
    assert per[1] == pytest.approx(fwiou_bruteforce(src[1], edit[1], 2, None), abs=EXACT)
    assert sem_cs(src, edit, num_classes=2) == pytest.approx(per.mean(), abs=EXACT)
    pooled = sem_cs(src, edit, num_classes=2, reduction="pooled")
    assert pooled == pytest.approx(fwiou_bruteforce(src, edit, 2, None), abs=EXACT)
    assert pooled != pytest.approx(per.mean())  # the two forms differ in general


def test_batch_equals_accumulated_and_functional_equals_class():
    rng = np.random.default_rng(3)
    src = rng.integers(0, 6, (5, 8, 10))
    edit = np.where(rng.random(src.shape) < 0.7, src, rng.integers(0, 6, src.shape))
    one = SemanticConsistency(None, num_classes=6)
    one.update(edit, source=src)
    many = SemanticConsistency(None, num_classes=6)
    for i in range(5):
        many.update(edit[i : i + 1], source=src[i : i + 1])
    a, b = one.compute(), many.compute()
    for key in ("sem_cs", "sem_cs_pooled"):
        assert a[key].value == pytest.approx(b[key].value, abs=EXACT)
    assert a["sem_cs"].value == pytest.approx(sem_cs(src, edit, num_classes=6), abs=EXACT)
    assert a["sem_cs_pooled"].value == pytest.approx(
        sem_cs(src, edit, num_classes=6, reduction="pooled"), abs=EXACT
    )
    np.testing.assert_allclose(a["sem_cs"].per_frame, sem_cs(src, edit, num_classes=6, reduction="none"))
    one.reset()
    assert one.compute()["sem_cs"].value is None
    clone = pickle.loads(pickle.dumps(many))
    assert clone.compute()["sem_cs"].value == b["sem_cs"].value


def test_confusion_orientation_rows_are_source():
    src, edit = np.array([[0, 0, 0, 1]]), np.array([[1, 1, 1, 1]])
    cms = confusion_matrices(src, edit, num_classes=2)
    np.testing.assert_array_equal(cms[0], [[0, 3], [0, 1]])
    # weights come from the source's class frequencies: 3/4 * 0 + 1/4 * 1/4
    assert fwiou(cms[0]) == pytest.approx(1 / 16, abs=EXACT)


def test_input_validation_names_shapes():
    with pytest.raises(ValueError, match=r"labels0 has shape \(2, 3\) but labels1 has shape \(3, 2\)"):
        sem_cs(np.zeros((2, 3), int), np.zeros((3, 2), int), num_classes=2)
    with pytest.raises(ValueError, match="integer label maps"):
        sem_cs(np.zeros((2, 2)), np.zeros((2, 2)), num_classes=2)
    with pytest.raises(ValueError, match="label 7 is outside"):
        sem_cs(np.full((2, 2), 7), np.zeros((2, 2), int), num_classes=3)
    with pytest.raises(ValueError, match="reduction"):
        sem_cs(np.zeros((2, 2), int), np.zeros((2, 2), int), num_classes=2, reduction="sum")


class _ThresholdSegmenter:
    """A tiny injected segmenter: class = 2 * (red > 0.5) + (green > 0.5); counts its calls."""

    name = "threshold-test"

    def __init__(self) -> None:
        self.frames = 0

    def __call__(self, images: np.ndarray) -> np.ndarray:
        self.frames += images.shape[0]
        return (2 * (images[..., 0] > 0.5) + (images[..., 1] > 0.5)).astype(np.int64)

    def config(self) -> dict:
        return {"kind": "threshold"}


def test_metric_with_injected_segmenter_and_source_cache():
    rng = np.random.default_rng(1)
    src = rng.random((3, 6, 7, 3)).astype(np.float32)
    edit = np.clip(src + rng.normal(0, 0.2, src.shape), 0, 1).astype(np.float32)
    seg = _ThresholdSegmenter()
    m = SemanticConsistency(seg, num_classes=4)
    m.update(edit, source=src)
    out = m.compute()
    expected = sem_cs(seg(src), seg(edit), num_classes=4)
    assert out["sem_cs"].value == pytest.approx(expected, abs=EXACT)
    assert "threshold-test" in out["sem_cs"].variant and "pooled" in out["sem_cs_pooled"].variant
    assert m.config()["segmenter"] == "threshold-test" and m.config()["model"] == {"kind": "threshold"}
    calls = seg.frames
    m.reset()
    m.update(edit, source=src)  # the same source frames: segmented from the cache
    assert seg.frames == calls + 3
    assert m.compute()["sem_cs"].value == pytest.approx(expected, abs=EXACT)


def test_metric_rejects_wrong_segmenter_output_and_missing_source():
    m = SemanticConsistency(lambda x: np.zeros((1, 2, 2), int), num_classes=2, segmenter_name="bad")
    with pytest.raises(ValueError, match=r"returned labels of shape \(1, 2, 2\)"):
        m.update(np.zeros((1, 4, 4, 3), np.float32), source=np.zeros((1, 4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="source frames are required"):
        m.update(np.zeros((1, 4, 4, 3), np.float32))


def test_skip_reasons_fog_and_missing_weights(tmp_path):
    from wcbench.core.models.store import ModelStore

    ctx = MetricContext(weather="rain", n_frames=3, has_reference=False)
    m = SemanticConsistency("segformer-b0-ade", store=ModelStore(root=tmp_path))
    reason = m.skip_reason(ctx)
    assert reason is not None
    assert (
        "wcbench models pull segformer-b0-ade" in reason
        and "wcbench models import segformer-b0-ade" in reason
    )
    assert "nvidia/segformer-b0-finetuned-ade-512-512" in reason
    assert m.config()["segmenter"] == "segformer-b0-ade" and m.config()["model"] == {}  # not installed yet
    fog = MetricContext(weather="fog", n_frames=3, has_reference=False)
    assert "fog" in SemanticConsistency(None).skip_reason(fog)
    assert SemanticConsistency(None).skip_reason(ctx) is None
    assert SemanticConsistency.compares_content and not SemanticConsistency.needs_reference


def test_shared_metric_tester():
    rng = np.random.default_rng(8)
    src = rng.random((4, 6, 5, 3))
    edit = np.clip(src + rng.normal(0, 0.15, src.shape), 0, 1)
    seg = _ThresholdSegmenter()
    functional = {  # the functional form on the segmenter's label maps
        "sem_cs": lambda p, s, r: sem_cs(seg(s), seg(p), num_classes=4),
        "sem_cs_pooled": lambda p, s, r: sem_cs(seg(s), seg(p), num_classes=4, reduction="pooled"),
    }
    out = check_metric(lambda: SemanticConsistency(_ThresholdSegmenter(), num_classes=4), edit, source=src,
                       functional=functional)
    assert 0 < out["sem_cs"].value < 1
    # labels mode gives the same numbers (the tester's float-dtype pass does not apply to labels)
    seg, labels = _ThresholdSegmenter(), SemanticConsistency(None, num_classes=4)
    labels.update(seg(edit), source=seg(src))
    assert labels.compute()["sem_cs"].value == pytest.approx(out["sem_cs"].value, abs=EXACT)
