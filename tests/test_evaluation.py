"""End to end: evaluate from files alone, idempotent re-runs, resume after SIGKILL, run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from scene_fixtures import write_prediction_folder

from wcbench.cli import main
from wcbench.results import CSV_COLUMNS, SCHEMA_VERSION


def _numbers(path: Path) -> dict:
    doc = json.loads(path.read_text())
    return {k: doc[k] for k in ("results", "skipped", "inputs", "config", "schema_version")}


def test_skipped_metrics_are_said_once_per_reason_most_rows_first():
    from wcbench.evaluation import skipped_causes

    weights = "weights not installed: run `wcbench models pull clip-vit-b32-openai`"
    doc = {"skipped": [
        *({"scene": s, "weather": w, "metric": m, "reason": weights}
          for s in ("demo", "pandaset_002") for w in ("rain", "snow") for m in ("clip_s", "clip_ds")),
        {"scene": "demo", "weather": "clear", "metric": "fps", "reason": "no timing"},
    ]}
    assert skipped_causes(doc) == [(weights, ["clip_ds", "clip_s"], 8), ("no timing", ["fps"], 1)]
    assert skipped_causes({"skipped": []}) == []


def _darken(img, k, weather):
    return (img * 0.8).astype(np.uint8)


def test_folder_evaluate_on_real_scene_writes_both_files(pandaset_root, tmp_path, capsys):
    from wcbench.scenes.loaders import load_scene

    scene = load_scene(pandaset_root)
    preds = write_prediction_folder(scene, tmp_path / "preds", ["clear"], transform=_darken)
    out = tmp_path / "out"
    args = ["evaluate", "--method", "folder", "--scenes", "pandaset_002", "--data-root", str(pandaset_root.parent),
            "--predictions", str(preds), "--out", str(out), "--metrics", "psnr", "temporal_flicker", "fps"]
    assert main(args) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["schema_version"] == SCHEMA_VERSION
    res = doc["results"]["pandaset_002"]["clear"]
    assert 10 < res["psnr"]["value"] < 30
    assert len(res["psnr"]["per_frame"]) == 30
    assert res["temporal_flicker_ratio"]["value"] == pytest.approx(0.8, abs=0.05)
    assert doc["skipped"] == [{"scene": "pandaset_002", "weather": "clear", "metric": "fps",
                               "reason": "no timing: the predictions have no info.json with timings and --fps "
                                         "was not given"}]
    assert len(doc["inputs"]["scenes"]["pandaset_002"]["clear"]["predictions"]) == 30
    df = pd.read_csv(out / "results.csv")
    assert tuple(df.columns) == CSV_COLUMNS
    assert set(df["status"]) == {"ok", "skipped"}
    printed = capsys.readouterr().out
    assert "skipped fps (1 row): no timing: the predictions have no info.json" in printed
    assert "  pandaset_002     clear  psnr" in printed
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(args) == 0
    assert "up to date" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


def test_identical_images_give_null_psnr_with_reason(demo_scene, tmp_path):
    preds = write_prediction_folder(demo_scene, tmp_path / "preds", ["clear"])
    out = tmp_path / "out"
    assert main(["evaluate", "--method", "folder", "--scenes", "demo", "--predictions", str(preds),
                 "--out", str(out), "--metrics", "psnr,ssim"]) == 0
    text = (out / "results.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    psnr = json.loads(text)["results"]["demo"]["clear"]["psnr"]
    assert psnr["value"] is None and "identical" in psnr["reason"]
    assert json.loads(text)["results"]["demo"]["clear"]["ssim"]["value"] == 1.0


def test_changed_inputs_refuse_to_overwrite_then_overwrite(demo_scene, tmp_path, capsys):
    preds = write_prediction_folder(demo_scene, tmp_path / "preds", ["rain"], transform=_darken)
    out = tmp_path / "out"
    args = ["evaluate", "--method", "folder", "--scenes", "demo", "--predictions", str(preds), "--out", str(out),
            "--metrics", "temporal_flicker"]
    assert main(args) == 0
    first = (out / "results.json").read_bytes()
    img = cv2.imread(str(preds / "rain" / "005.png"))
    cv2.imwrite(str(preds / "rain" / "005.png"), 255 - img)
    assert main(args) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (out / "results.json").read_bytes() == first
    assert main([*args, "--overwrite"]) == 0
    assert (out / "results.json").read_bytes() != first


def test_killed_run_resumes_with_identical_numbers(demo_scene, tmp_path):
    preds = write_prediction_folder(demo_scene, tmp_path / "preds", ["clear", "rain", "snow", "fog"],
                                    transform=lambda img, k, w: np.roll(img, k * (1 + len(w)), axis=1))
    base = [sys.executable, "-m", "wcbench", "evaluate", "--method", "folder", "--scenes", "demo",
            "--predictions", str(preds), "--metrics", "ssim,temporal_flicker,flow_warping_error"]
    env = dict(os.environ, WCBENCH_PROGRESS="0")
    ref_out, out = tmp_path / "ref", tmp_path / "killed"
    # cwd outside the source tree: `python -m` puts the cwd first on sys.path
    subprocess.run([*base, "--out", str(ref_out)], check=True, env=env, capture_output=True, cwd=tmp_path)
    proc = subprocess.Popen([*base, "--out", str(out)], env=env, stdout=subprocess.DEVNULL, cwd=tmp_path)
    work = out / ".work" / "demo"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (work.is_dir() and any(work.glob("*.json"))):
        time.sleep(0.002)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "results.json").exists(), "the run finished before it could be killed midway"
    done = len(list(work.glob("*.json")))
    assert 1 <= done < 4
    result = subprocess.run([*base, "--out", str(out)], env=env, capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert f"({4 - done} computed, {done} reused)" in result.stdout
    a, b = _numbers(ref_out / "results.json"), _numbers(out / "results.json")
    assert a == b


def test_run_renders_then_evaluates_and_resumes(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["run", "--method", "filter2d", "--scenes", "demo", "--out", str(out),
            "--weathers", "rain,fog", "--metrics", "temporal_flicker,fps"]
    assert main(args) == 0
    info = json.loads((out / "filter2d" / "demo" / "rain" / "info.json").read_text())
    assert info["method"] == "filter2d" and len(info["frames"]) == 12
    assert info["timings"]["fps"] > 0 and info["timings"]["resolution"] == [320, 180]
    doc = json.loads((out / "results.json").read_text())
    fps = doc["results"]["demo"]["rain"]["fps"]
    assert fps["value"] == pytest.approx(info["timings"]["fps"])
    frames_before = {p: p.stat().st_mtime_ns for p in (out / "filter2d").rglob("*.png")}
    assert main(args) == 0
    assert "up to date" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in (out / "filter2d").rglob("*.png")} == frames_before


def test_run_is_deterministic_under_a_seed(tmp_path):
    for name in ("a", "b"):
        assert main(["run", "--method", "filter2d", "--scenes", "demo", "--out", str(tmp_path / name),
                     "--weathers", "snow", "--metrics", "temporal_flicker", "--seed", "3"]) == 0
    a = sorted((tmp_path / "a" / "filter2d").rglob("*.png"))
    b = sorted((tmp_path / "b" / "filter2d").rglob("*.png"))
    assert [p.read_bytes() for p in a] == [p.read_bytes() for p in b]
    assert _numbers(tmp_path / "a" / "results.json")["results"] == _numbers(tmp_path / "b" / "results.json")["results"]


def test_identity_method_is_perfect_on_content(tmp_path):
    out = tmp_path / "id"
    assert main(["run", "--method", "identity", "--scenes", "demo", "--out", str(out), "--weathers", "clear,rain",
                 "--metrics", "ssim,temporal_flicker"]) == 0
    res = json.loads((out / "results.json").read_text())["results"]["demo"]
    assert res["clear"]["ssim"]["value"] == 1.0
    assert res["rain"]["temporal_flicker_ratio"]["value"] == 1.0


def test_metric_resolution_scores_downscaled_frames_and_says_so(pandaset_root, tmp_path, capsys):
    from wcbench.scenes.loaders import load_scene

    scene = load_scene(pandaset_root)
    preds = write_prediction_folder(scene, tmp_path / "preds", ["clear"], transform=_darken)
    base = ["evaluate", "--method", "folder", "--scenes", str(pandaset_root), "--predictions", str(preds),
            "--metrics", "psnr", "temporal_flicker", "--no-progress"]
    assert main([*base, "--out", str(tmp_path / "default")]) == 0
    assert main([*base, "--out", str(tmp_path / "native"), "--metric-resolution", "native"]) == 0
    small, full = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("default", "native"))
    assert small["config"]["metric_resolution"] == 960 and full["config"]["metric_resolution"] is None
    [record] = small["working_size"]
    assert (record["from"], record["to"], record["metric_resolution"]) == ([1920, 1080], [960, 540], 960)
    assert full["working_size"] == []
    p_small, p_full = (d["results"]["pandaset_002"]["clear"]["psnr"] for d in (small, full))
    assert p_small["variant"].endswith("; scored at 960x540") and "scored at" not in p_full["variant"]
    # a uniform darkening commutes with area downscaling up to rounding: the same PSNR, near enough
    assert p_small["value"] == pytest.approx(p_full["value"], abs=0.2)
    assert p_small["value"] != p_full["value"]
    with pytest.raises(SystemExit) as exc:  # argparse refuses it before any work
        main([*base, "--out", str(tmp_path / "bad"), "--metric-resolution", "12"])
    assert exc.value.code == 2 and "'native' or the longer side in pixels" in capsys.readouterr().err


def test_every_method_of_a_scene_is_scored_at_the_scenes_working_size(tmp_path):
    """A method rendering at half the scene's size is scored at the scene's working size, as one
    rendering at the scene's size is: the same definitions, the resize recorded; a size asked for
    on ``evaluate`` is scored there instead."""
    common = ["--scenes", "demo", "--weathers", "rain", "--frames", "0-3", "--metrics", "temporal_flicker",
              "fps", "--no-progress"]
    assert main(["run", "--method", "filter2d", "--scale", "0.5", "--out", str(tmp_path / "half"), *common]) == 0
    assert main(["run", "--method", "identity", "--out", str(tmp_path / "full"), *common]) == 0
    half, full = (json.loads((tmp_path / d / "results.json").read_text()) for d in ("half", "full"))
    rule = {"rule": "scene working size", "sizes": {"demo": [320, 180]}}
    assert half["config"]["scored_at"] == full["config"]["scored_at"] == rule
    [record] = half["working_size"]
    assert (record["from"], record["to"], record["predictions"]) == ([320, 180], [320, 180], [160, 90])
    assert record["predictions_resized"] and record["rule"] == "scene working size"
    assert "bicubic" in record["interpolation"]
    assert full["working_size"] == []
    h, f = (d["results"]["demo"]["rain"] for d in (half, full))
    assert {o: r["variant"] for o, r in h.items()} == {o: r["variant"] for o, r in f.items()}
    assert not any("scored at" in r["variant"] for r in h.values())
    assert len(h["temporal_flicker"]["per_frame"]) == 3
    assert h["fps"]["extra"]["resolution"] == [160, 90]  # FPS stays the method's own, at its render size
    # evaluate --scale: scored at the size asked for, said in the variants
    assert main(["evaluate", "--method", "filter2d", "--predictions", str(tmp_path / "half" / "filter2d"),
                 "--scale", "0.5", "--out", str(tmp_path / "asked"), *common]) == 0
    asked = json.loads((tmp_path / "asked" / "results.json").read_text())
    assert asked["config"]["scored_at"] == {"rule": "asked", "sizes": {"demo": [160, 90]}}
    [record] = asked["working_size"]
    assert (record["to"], record["predictions_resized"], record["rule"]) == ([160, 90], False, "asked")
    assert asked["results"]["demo"]["rain"]["temporal_flicker"]["variant"].endswith("; scored at 160x90")


def test_results_scored_under_the_earlier_size_rule_are_never_served_as_up_to_date(tmp_path, capsys):
    """A results.json of an earlier wcbench (a method scored at its own render size, no
    ``config.scored_at``) is other settings: refused, never returned as up to date."""
    from wcbench.core.storage import sha256_json
    from wcbench.results import results_checksum

    args = ["run", "--method", "filter2d", "--scenes", "demo", "--weathers", "rain", "--frames", "0-3", "--scale",
            "0.5", "--metrics", "temporal_flicker", "--no-progress", "--out", str(tmp_path / "out")]
    assert main(args) == 0
    path = tmp_path / "out" / "results.json"
    doc = json.loads(path.read_text())
    del doc["config"]["scored_at"]  # as an earlier wcbench wrote it
    doc["inputs"]["sha256"] = sha256_json({"inputs": doc["inputs"]["scenes"], "config": doc["config"]})
    doc["checksum"] = results_checksum(doc)
    path.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(args) == 2
    assert "other inputs or settings" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0
    assert "scored_at" in json.loads(path.read_text())["config"]


def test_worker_threads_and_kept_frames_change_no_number(demo_scene, tmp_path, monkeypatch):
    """The fast scoring path (decoding threads, predictions decoded once by the check and kept, raw
    frames shared by units) against its twin (one thread, every frame decoded where it is used):
    the same numbers to the bit, with each prediction decoded once instead of twice."""
    import wcbench.predictions as predictions_module
    from wcbench.evaluation import EvaluateConfig, evaluate
    from wcbench.metrics.temporal.flicker import FLOW_CACHE
    from wcbench.units import FRAME_CACHE

    preds = write_prediction_folder(demo_scene, tmp_path / "preds", ["clear", "rain", "snow"], transform=_darken)
    real_read = predictions_module.read_rgb8
    reads: list[str] = []

    def counting_read(path):
        reads.append(str(path))
        return real_read(path)

    monkeypatch.setattr(predictions_module, "read_rgb8", counting_read)
    docs = {}
    for name, fast, threads in (("twin", False, "1"), ("fast", True, "2")):
        monkeypatch.setenv("WCBENCH_THREADS", threads)
        FRAME_CACHE.clear()
        FLOW_CACHE.clear()
        reads.clear()
        cfg = EvaluateConfig(method="folder", scenes="demo", predictions=preds, out=tmp_path / name,
                             weathers=["clear", "rain", "snow"], metrics=["psnr", "ssim", "temporal_flicker",
                                                                          "flow_warping_error"],
                             prefetch_frames=fast, share_frames=fast, show_progress=False)
        docs[name] = evaluate(cfg).results
        assert len(reads) == (1 if fast else 2) * 3 * len(demo_scene), name
    assert docs["fast"]["results"] == docs["twin"]["results"]
    assert FRAME_CACHE.nbytes == len(demo_scene) * 320 * 180 * 3  # only the raw frames stay, for other units


def test_results_carry_the_raw_frames_scored_against_a_truth(tmp_path, monkeypatch):
    """With a rain truth (here the scene's own frames in reverse order), results.json holds the raw
    frames' PSNR and SSIM against it, equal to the identity method's (which returns the raw frames)."""
    from wcbench.scenes.scene import Scene

    def truth(self, weather):
        frames = [f.image_path for f in self.frames]
        return frames if weather == "clear" else frames[::-1]

    monkeypatch.setattr(Scene, "reference_paths", truth)
    out = tmp_path / "identity"
    assert main(["run", "--method", "identity", "--scenes", "demo", "--out", str(out), "--weathers", "rain",
                     "clear", "--metrics", "psnr", "ssim", "--no-progress"]) == 0
    doc = json.loads((out / "results.json").read_text())
    raw = doc["raw_frames"]["demo"]
    assert set(raw) == {"rain"}  # clear's truth is the raw frames themselves: no yardstick row
    for output in ("psnr", "ssim"):
        scored = doc["results"]["demo"]["rain"][output]["value"]
        assert raw["rain"][output]["value"] == pytest.approx(scored, rel=1e-9)
        assert 0 < scored < (1.0 if output == "ssim" else 60.0)  # a real comparison, not frames with themselves
