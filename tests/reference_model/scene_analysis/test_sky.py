"""Sky segmentation: the boundary placed by colour, the rotation's warp, the harder synthetic
street's truth, and the hand-drawn masks of the real cameras (docs/design.md §7, "Sky")."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from paths import DATA, SHARED_DATA

pytest.importorskip("torch")

from wcbench.reference_model.scene_analysis.analysis import analyse_scene
from wcbench.reference_model.scene_analysis.sky import (
    _cut,
    infinity_residual,
    refine_boundary,
    segment_sky,
    sky_matte,
    thin_returns,
)
from wcbench.reference_model.scene_analysis.views import AnalysisViews, resample_mask


def test_the_boundary_follows_the_sky_share_of_each_pixel():
    # a sky (blue) above a wall (brown) whose edge crosses row 10 at a quarter, a half and three quarters
    h, w = 20, 30
    sky, wall = np.array([0.5, 0.6, 0.9], np.float32), np.array([0.4, 0.25, 0.2], np.float32)
    image = np.empty((h, w, 3), np.float32)
    image[:10], image[10:] = sky, wall
    shares = np.array([0.25, 0.5, 0.75])
    image[10, :10] = shares[0] * sky + (1 - shares[0]) * wall
    image[10, 10:20] = shares[1] * sky + (1 - shares[1]) * wall
    image[10, 20:] = shares[2] * sky + (1 - shares[2]) * wall
    cut = np.zeros((h, w), bool)
    cut[:12] = True  # the cut went two rows too far
    mask, alpha = refine_boundary(image, cut, np.zeros((h, w), bool))
    # the row of mixed pixels takes its share (CIELAB is not linear in RGB: within 0.12)
    np.testing.assert_allclose(alpha[10, 2:8], shares[0], atol=0.12)
    np.testing.assert_allclose(alpha[10, 22:28], shares[2], atol=0.12)
    assert not mask[11].any() and mask[9].all()  # the wall's rows are wall again, the sky's sky
    assert not mask[10, :8].any() and mask[10, 22:28].all()  # sky where the share is over one half
    # a pixel the lidar hits is never sky, whatever its colour
    never = np.zeros((h, w), bool)
    never[5, 5] = True
    mask, alpha = refine_boundary(image, cut, never)
    assert not mask[5, 5] and alpha[5, 5] < 0.5


def test_a_third_colour_at_the_boundary_takes_its_share_from_the_surface_that_explains_it():
    # a blue sky over a pale far building with a dark pillar; the cut went two rows into the building
    h, w = 24, 32
    sky, pale, dark = (np.array(c, np.float32) for c in ([0.45, 0.6, 0.95], [0.92, 0.88, 0.75], [0.05, 0.05, 0.08]))
    image = np.empty((h, w, 3), np.float32)
    image[:10], image[10:] = sky, pale
    image[10:, 15:17] = dark
    cut = np.zeros((h, w), bool)
    cut[:12] = True
    never = np.zeros((h, w), bool)
    mask, alpha = refine_boundary(image, cut, never)
    # beside the pillar the farthest colour is the dark one, on whose line with the sky the pale top
    # lies near the sky's end; the pale surface below explains it exactly: building, not sky
    assert not mask[10:12].any() and mask[:10].all()
    np.testing.assert_allclose(alpha[10:12], 0.0, atol=1e-6)
    # without the rule (any distortion accepted) the pale top beside the pillar is called sky
    mask_line, _ = refine_boundary(image, cut, never, max_distortion=np.inf)
    assert mask_line[10:12, 12:20].any()
    # and a pixel on the line (a mixed pixel of the sky and the pillar) keeps the colour line's share
    image[9, 15:17] = 0.7 * sky + 0.3 * dark
    mask, alpha = refine_boundary(image, cut, never)
    np.testing.assert_allclose(alpha[9, 15:17], 0.7, atol=0.12)


def test_the_matte_feathers_only_the_boundary_and_keeps_lidar_hits_under_a_half():
    image = np.full((12, 12, 3), 0.3, np.float32)
    image[:6] = 0.8
    mask = np.zeros((12, 12), bool)
    mask[:6] = True
    solid = np.zeros((12, 12), bool)
    solid[5, 3] = True
    alpha = sky_matte(mask, image, solid, radius=2)
    assert alpha[0].min() == 1.0 and alpha[-1].max() == 0.0  # far from the boundary: the label
    assert alpha[5, 3] < 0.5


def _views(images: list[np.ndarray], rotations: list[np.ndarray], *, focal_px: float = 100.0) -> AnalysisViews:
    h, w = images[0].shape[:2]
    K = np.array([[focal_px, 0, w / 2], [0, focal_px, h / 2], [0, 0, 1]])
    poses = []
    for R in rotations:
        T = np.eye(4)
        T[:3, :3] = R
        poses.append(T)
    return AnalysisViews(size=(w, h), images=images, K=[K] * len(images), camera_to_world=poses,
                         up=np.array([0.0, -1.0, 0.0]), times=np.arange(len(images)) / 10.0)


def test_a_patch_of_sky_behind_a_lamp_arm_is_kept_and_one_inside_a_wall_is_not():
    from wcbench.reference_model.scene_analysis.sky import _sky_components

    mask = np.zeros((60, 80), bool)
    mask[:20] = True                 # the open sky, reaching the top
    mask[22:35, 5:40] = True         # below a 2 px lamp arm (rows 20-21): the same sky
    mask[45:55, 50:70] = True        # a pane in a wall, 10 rows under the sky: not sky
    seeds = np.zeros_like(mask)
    seeds[2:5, 2:5] = True

    def kept_by(**kw):
        labels, kept = _sky_components(mask, seeds, **kw)
        return np.isin(labels, kept)

    kept = kept_by(bridge_px=2)
    assert kept[22:35, 5:40].all() and kept[:20].all()
    assert not kept[45:55, 50:70].any()
    assert not (kept & ~mask).any()  # the bridge joins patches, it adds no sky
    # without a bridge the arm cuts the patch off, as before
    assert not kept_by()[22:35, 5:40].any()


def test_a_patch_of_sky_one_frame_alone_sees_has_no_support_and_the_open_sky_has():
    from wcbench.reference_model.scene_analysis.sky import neighbour_support, rotation_homography

    # a camera turning 2 degrees a frame under a sky at infinity: frame k's sky, warped by the
    # rotation, is the sky of frame j; a patch only frame 2 calls sky (a facade between the lidar's
    # scan lines) is sky in no neighbour
    h, w = 60, 80
    rotations = []
    for k in range(5):
        a = np.radians(2.0 * k)
        rotations.append(np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]))
    views = _views([np.zeros((h, w, 3), np.float32)] * 5, rotations)
    masks = np.zeros((5, h, w), bool)
    masks[:, :20] = True            # the sky above the horizon's row 20 (a pure yaw keeps rows)
    masks[2, 30:40, 50:70] = True   # frame 2 alone
    labels = np.zeros((h, w), np.int32)
    labels[:20] = 1
    labels[30:40, 50:70] = 2
    support = neighbour_support(views, masks, 2, labels)
    assert np.isnan(support[0])
    assert support[1] > 0.95 and support[2] == 0.0
    # the same direction seen by frame 3 lies where the homography says, 2 degrees (~3.5 px) aside
    H = rotation_homography(views, 2, 3)
    p = H @ np.array([40.0, 10.0, 1.0])
    assert abs(p[0] / p[2] - 40.0 - 100.0 * np.tan(np.radians(-2.0))) < 0.2 and abs(p[1] / p[2] - 10.0) < 0.2
    # a scene of one frame has no neighbour to ask
    one = _views([np.zeros((h, w, 3), np.float32)], rotations[:1])
    assert np.isnan(neighbour_support(one, masks[:1], 0, labels)[1:]).all()


def test_the_infinity_residual_vanishes_under_a_pure_rotation(rng):
    # frames of a far-away texture seen by a camera that only turns: the rotation's homography
    # aligns them exactly, so the residual is ~0 (the sky); a translation would not be aligned
    h, w = 60, 80
    big = cv2.GaussianBlur(rng.random((400, 400, 3)).astype(np.float32), (0, 0), 2.0)
    K = np.array([[100.0, 0, w / 2], [0, 100.0, h / 2], [0, 0, 1]])
    shift = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])
    rotations, images = [], []
    for k in range(5):
        a = np.radians(2.0 * k)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        rotations.append(R)
        # image k: the texture (a plane at infinity, pixel = K R^T d) rendered by the inverse map
        H = np.linalg.inv(shift) @ K @ R.T @ np.linalg.inv(K) @ shift
        Hb = np.array([[1, 0, 160], [0, 1, 170], [0, 0, 1.0]]) @ np.linalg.inv(H)
        images.append(cv2.warpPerspective(big, Hb, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP))
    views = _views(images, rotations)
    res = infinity_residual(views, 2)
    assert float(res[8:-8, 8:-8].mean()) < 0.01
    # the same frames pretending the camera did not turn: the texture is misaligned
    still = _views(images, [np.eye(3)] * 5)
    assert float(infinity_residual(still, 2)[8:-8, 8:-8].mean()) > 3 * float(res[8:-8, 8:-8].mean())


@pytest.mark.model
def test_the_harder_street_sky_against_its_truth_and_never_on_a_lidar_return(synth_hard):
    analysis = analyse_scene(synth_hard)
    inter = union = 0
    for k in range(0, len(synth_hard), 3):
        truth = cv2.imread(str(synth_hard.root / "truth" / "masks" / "sky" / f"{k:03d}_0.png"), cv2.IMREAD_GRAYSCALE)
        t = resample_mask(truth > 127, analysis.views.size)
        p = analysis.sky.masks[k]
        inter, union = inter + int((t & p).sum()), union + int((t | p).sum())
        assert not (p & analysis.solid[k]).any()
    # its buildings rise above the lidar's reach: a lidar-only sky would take their upper floors
    assert inter / union >= 0.93


@pytest.mark.slow
@pytest.mark.model
@pytest.mark.parametrize("name, bound", [("pandaset_002", 0.965), ("pandaset_002_back", 0.975),
                                         ("pandaset_002_front_right", 0.965), ("pandaset_002_right", 0.98)])
def test_the_real_cameras_sky_against_the_hand_drawn_masks(name, bound):
    from wcbench.scenes.loaders import load_scene

    if not (SHARED_DATA / name / "images").is_dir():
        pytest.skip(f"{SHARED_DATA / name} not present")
    analysis = analyse_scene(load_scene(SHARED_DATA / name))
    inter = union = 0
    for k in (5, 15, 25):
        truth = cv2.imread(str(DATA / "sky_masks" / name / f"{k:03d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        t = resample_mask(truth, analysis.views.size)
        outside = ~analysis.solid[k]  # a pixel the lidar hits is never sky; the masks' rule is coverage
        p = analysis.sky.masks[k]
        inter += int((t & p & outside).sum())
        union += int(((t | p) & outside).sum())
    assert inter / union >= bound


@pytest.mark.model
def test_a_frame_no_lidar_return_lands_in_gets_no_invented_sky(synth_hard):
    analysis = analyse_scene(synth_hard)
    solid = [s.copy() for s in analysis.solid]
    k = 12
    solid[k][:] = False  # the lidar covers none of frame 12
    sky = segment_sky(analysis.views, solid)
    truth = cv2.imread(str(synth_hard.root / "truth" / "masks" / "sky" / f"{k:03d}_0.png"), cv2.IMREAD_GRAYSCALE) > 127
    t = resample_mask(truth, analysis.views.size)
    false_sky = sky.masks[k] & ~t
    # the scene's classifier, trained on the other frames, still finds its sky; no wall becomes sky
    assert false_sky.mean() < 0.01 and (sky.masks[k] & t).sum() > 0.8 * t.sum()


def _street_with_an_arm(*, arm_rows: slice = slice(28, 31)) -> tuple[AnalysisViews, list[np.ndarray]]:
    """Three still frames, 90 x 120 (horizon at row 45): a blue sky paling toward the horizon, two
    buildings the lidar hits (columns 0-29 and 90-119, from row 10 down), and a signal's mast arm
    (``arm_rows``, 3 px) the lidar hits too, spanning the street between them: the sky under the
    arm (rows 31-44, columns 30-89) is cut off from the open sky by returns."""
    h, w = 90, 120
    image = np.empty((h, w, 3), np.float32)
    t = (np.arange(h, dtype=np.float32) / 45.0).clip(0.0, 1.0)[:, None]
    # the clear sky's blue high up, paler (hazier) toward the horizon, the same hue
    image[..., 0], image[..., 1], image[..., 2] = 0.45 + 0.2 * t, 0.6 + 0.12 * t, 0.92 + 0.03 * t
    image[45:] = 0.35  # the road
    solid = np.zeros((h, w), bool)
    for cols in (slice(0, 30), slice(90, 120)):
        image[10:45, cols] = (0.55, 0.35, 0.3)  # brick
        solid[10:60, cols] = True
    image[arm_rows, 30:90] = 0.15
    solid[arm_rows, 30:90] = True
    solid[45:, :] = True  # the road's returns
    images = [image.copy() for _ in range(3)]
    return _views(images, [np.eye(3)] * 3), [solid.copy() for _ in range(3)]


def test_a_thin_occluder_is_a_wire_against_the_sky_and_not_a_wall_s_scan_line():
    from wcbench.reference_model.scene_analysis.sky import thin_occluders

    views, solid = _street_with_an_arm()
    image, s = views.images[0], solid[0]
    above = views.elevation(0) > 0.0
    sky = np.zeros_like(s)
    sky[:22, 35:85] = True  # the seeds above the arm
    thin = thin_occluders(image, s, above, sky)
    assert thin[28:31, 40:80].all()  # the arm, with the sky's colour above and below
    assert not thin[20:45, :30].any() and not thin[20:45, 90:].any()  # the buildings are not thin
    # a wall's scan line: a 2 px line of returns with the wall's colour on both sides is no occluder
    wall = image.copy()
    wall[20:45, 30:90] = (0.8, 0.78, 0.7)
    lines = s.copy()
    lines[28:31] = False
    lines[34:36, 30:90] = True
    assert not thin_occluders(wall, lines, above, sky)[34:36].any()
    # without sky seeds nearby nothing is crossed
    assert not thin_occluders(image, s, above, np.zeros_like(s)).any()
    with pytest.raises(ValueError, match="one"):
        thin_occluders(image, s[:10], above, sky)


def test_the_hazy_sky_under_a_mast_arm_the_lidar_hits_is_sky_and_the_arm_is_not():
    views, solid = _street_with_an_arm()
    sky = segment_sky(views, solid)
    under = np.zeros((90, 120), bool)
    under[33:43, 34:86] = True  # the sky under the arm, off its mixed pixels and the buildings
    for k in range(3):
        assert sky.masks[k][under].mean() > 0.95
        assert sky.masks[k][:8, 40:80].all()  # the open sky
        assert not (sky.masks[k] & solid[k]).any()  # the arm and the buildings stay non-sky
        assert not sky.masks[k][12:44, 2:28].any() and not sky.masks[k][12:44, 92:118].any()


def test_another_sweep_s_copy_of_a_crossed_arm_stays_non_sky():
    views, solid = _street_with_an_arm()
    copies = []
    for s in solid:
        u = s.copy()
        u[31, 30:90] = True  # another sweep's copy of the arm, 1 px lower (4 px at 480 wide: its registration)
        copies.append(u)
    sky = segment_sky(views, solid, untrusted=copies)
    for k in range(3):
        assert not sky.masks[k][31, 30:90].any()
        assert sky.masks[k][34:43, 34:86].mean() > 0.95
    with pytest.raises(ValueError, match="one per frame"):
        segment_sky(views, solid, untrusted=copies[:1])


def _sky_with_wires(h: int = 90, w: int = 120) -> tuple[AnalysisViews, np.ndarray]:
    """Three still frames: a blue sky paling toward the horizon (row 45), a brick building across the
    frame from row 30 down, and three dark wires 1 px wide at rows 19, 23 and 27: every pixel of the
    sky from row 17 to the roof line is within 2 px of a wire. Returns the views and the sky between
    the wires and the roof."""
    image = np.empty((h, w, 3), np.float32)
    t = (np.arange(h, dtype=np.float32) / 45.0).clip(0.0, 1.0)[:, None]
    # the clear sky's blue (CIELAB a* about 2, b* about -40: seeds above the lidar's coverage too)
    image[..., 0], image[..., 1], image[..., 2] = 0.45 + 0.1 * t, 0.65 + 0.05 * t, 0.92 + 0.03 * t
    image[30:45] = (0.55, 0.35, 0.3)  # brick
    image[45:] = 0.35  # the road
    for row in (19, 23, 27):
        image[row] = 0.12
    strip = np.zeros((h, w), bool)
    strip[[20, 21, 22, 24, 25, 26, 28], 4:-4] = True
    return _views([image.copy() for _ in range(3)], [np.eye(3)] * 3), strip


def test_wires_across_the_sky_do_not_make_it_rough():
    from wcbench.reference_model.scene_analysis.sky import sky_features

    views, strip = _sky_with_wires()
    image, elev = views.images[0], views.elevation(0)
    residual = np.zeros(elev.shape, np.float32)
    closed = sky_features(image, residual, elev)
    raw = sky_features(image, residual, elev, line_px=0)
    # the 5 x 5 deviation and the gradient between the wires (off the roof's reach) are the open sky's
    between = strip & (np.arange(strip.shape[0]) <= 26)[:, None]
    open_sky = closed[2:12, 4:-4][..., [3, 5]].max(axis=(0, 1))
    assert (closed[between][:, [3, 5]].max(axis=0) <= open_sky + 0.02).all()
    assert (raw[between][:, 3] > 10 * 0.03).all()  # without closing every pixel there is rough
    # the colour stays the image's: a wire is dark in L*
    assert closed[19, 60, 0] < 0.5 < closed[21, 60, 0]
    with pytest.raises(ValueError, match="line_px"):
        sky_features(image, residual, elev, line_px=-1)


def test_a_wire_across_a_roof_line_does_not_lead_the_sky_into_the_wall_below():
    # three still frames at the analysis size (480 x 270, a focal length of 490 px as PandaSet's
    # front camera there; horizon at row 135): a blue sky, a smooth dark facade from row 60 down that
    # the lidar hits only from row 120 (rows 60-76 lie above a wall's continuation of 5 degrees and
    # within the lidar's coverage of 12), and a wire the lidar hits above the roof line only (now
    # and then: not where the facade is behind it), running down from the top-left across the roof
    # line at column 120: a thin occluder while the sky is on both its sides. Crossing it must not
    # cross the roof line (pandaset_002_back, frame 12).
    h, w = 270, 480
    image = np.empty((h, w, 3), np.float32)
    t = (np.arange(h, dtype=np.float32) / 135.0).clip(0.0, 1.0)[:, None]
    image[..., 0], image[..., 1], image[..., 2] = 0.45 + 0.1 * t, 0.65 + 0.05 * t, 0.92 + 0.03 * t
    image[60:135] = (0.22, 0.25, 0.3)  # the facade: dark blue-grey, smooth
    image[135:] = 0.35
    solid = np.zeros((h, w), bool)
    solid[120:] = True
    for r in range(0, 120):  # the wire: 1 px, 45 degrees
        image[r, 60 + r] = 0.12
        solid[r, 60 + r] = r < 60
    views = _views([image.copy() for _ in range(3)], [np.eye(3)] * 3, focal_px=490.0)
    sky = segment_sky(views, [solid.copy() for _ in range(3)])
    for k in range(3):
        assert sky.masks[k][:50, 200:].all()  # the open sky
        assert not sky.masks[k][63:120].any()  # the wall, below its roof line's mixed rows


def test_sky_coloured_thin_returns_pull_no_pocket_of_sky_to_the_wall_in_the_cut():
    # a pocket of pale sky (weak evidence, p = 0.6) fenced by a 1 px line of returns of the sky's
    # colour (a wire's copy a px off) beside a dark wall: joined to the returns by the smoothness
    # term the pocket goes with them; with the returns loose it is sky
    h, w = 40, 40
    image = np.full((h, w, 3), (0.62, 0.74, 0.9), np.float32)
    image[:, :10] = (0.3, 0.3, 0.3)  # the wall
    p = np.full((h, w), 0.6, np.float32)
    p[:, :10] = 0.05
    never = np.zeros((h, w), bool)
    never[:, :10] = True
    never[12, 10:] = True  # the line of returns across the sky
    never[12:30, 30] = True  # and down, closing the pocket to the right
    never[30, 10:31] = True
    always = np.zeros((h, w), bool)
    always[:5, 20:] = True  # seeds above the line
    pocket = np.zeros((h, w), bool)
    pocket[13:30, 10:30] = True
    fenced = _cut(image, p, never, always)
    assert not fenced[pocket].any() and fenced[always].all()
    loose = never & (np.arange(w) >= 10)[None, :]  # the line, not the wall
    free = _cut(image, p, never, always, loose=loose)
    assert free[pocket].all() and not free[never].any()


def test_a_pocket_of_the_sky_s_own_blue_joined_to_it_is_sky_and_a_blue_sign_is_not():
    from wcbench.reference_model.scene_analysis.sky import _blue_pockets

    h, w = 48, 48
    sky_blue, wall = (0.55, 0.70, 0.95), (0.45, 0.45, 0.42)
    image = np.full((h, w, 3), wall, np.float32)
    image[:10, 10:] = sky_blue           # the open sky, as cut
    image[10:30, 12:24] = sky_blue       # a pocket below it, joined along row 10
    image[14:20, 30:40] = (0.10, 0.25, 0.75)  # a saturated blue sign, joined to the sky through
    image[10:14, 30:40] = sky_blue            # a strip of the sky's blue above it
    image[38:44, 20:30] = sky_blue       # the sky's blue apart from the sky (a window's reflection)
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2Lab)
    sky = np.zeros((h, w), bool)
    sky[:10, 10:] = True
    free = np.ones((h, w), bool)
    free[20, 12:18] = False              # a return (any sweep's) in the pocket
    grown = _blue_pockets(lab, sky, free)
    pocket = np.zeros((h, w), bool)
    pocket[10:30, 12:24] = True
    assert grown[pocket & free].all() and not grown[~free].any()
    assert grown[10:14, 30:40].all() and not grown[14:20, 30:40].any()
    assert not grown[38:44, 20:30].any() and not grown[image[..., 0] < 0.5].any()
    assert not (grown & sky).any()
    # what the cut gave nothing to grow from stays empty
    assert not _blue_pockets(lab, np.zeros_like(sky), free).any()


def test_thin_returns_are_the_structures_no_square_fits_in():
    solid = np.zeros((30, 30), bool)
    solid[5, :] = True  # a wire, 1 px
    solid[10:30, 10:20] = True  # a wall, 10 px wide
    thin = thin_returns(solid, width_px=3)
    assert thin[5].all() and not thin[15:25, 12:18].any()
