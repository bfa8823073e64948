"""The report from result files: merged folders, flags, dashes, exports, frames, determinism."""

from __future__ import annotations

import csv
import html
import io
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from report_helpers import expected_text, parse_report, result_values, rewrite_results, skip_output

from wcbench.cli import main
from wcbench.reports import build_report
from wcbench.reports.tables import RAW_FRAMES


def _numeric(cells):
    return [c for c in cells if c["value"][:1].isdigit()]


def test_merged_folders_give_one_table_with_every_method_and_correct_numbers(small, tmp_path):
    out = tmp_path / "r.html"
    outcome = build_report(list(small.values()), out)
    parsed = parse_report(out)
    main_cells = [c for c in parsed.cells if c["table"] == "t-paper"]
    assert {c["data-method"] for c in main_cells} == set(small)
    values = result_values(list(small.values()))
    numeric = _numeric(parsed.cells)
    assert len(numeric) > 100
    for cell in numeric:
        decimals = len(cell["value"].split(".")[1])
        assert cell["value"] == expected_text(values, cell, decimals), cell
    # the paper's metrics keep the paper's 3 decimals
    assert all(len(c["value"].split(".")[1]) == 3 for c in _numeric(main_cells))
    assert outcome.n_images > 0 and outcome.size_bytes == out.stat().st_size


def test_best_bold_second_underlined_per_column(small, tmp_path):
    out = tmp_path / "r.html"
    build_report(list(small.values()), out)
    cells = [c for c in parse_report(out).cells if c["table"] == "t-paper" and c["value"][:1].isdigit()]
    columns: dict[tuple[str, str], list[dict]] = {}
    for c in cells:
        columns.setdefault((c["data-weather"], c["data-output"]), []).append(c)
    assert columns
    for col in columns.values():
        order = sorted(col, key=lambda c: float(c["value"]), reverse=True)  # all paper metrics: higher is better
        ranks = [re.search(r"\br([12])\b", c["class"]) for c in order]
        assert ranks[0] and ranks[0].group(1) == "1"
        assert ranks[1] and ranks[1].group(1) == "2"
        assert all(r is None for r in ranks[2:])


def test_skipped_cell_is_a_dash_with_its_reason_as_title(small, tmp_path):
    reason = "weights for clip-vit-b32-openai not installed: run `wcbench models pull clip-vit-b32-openai`"
    rewrite_results(small["haze"], lambda d: skip_output(d, "scene_a", "rain", "clip_s", reason))
    out = tmp_path / "r.html"
    build_report(list(small.values()), out)
    cells = parse_report(out).cells
    scene_cell = next(c for c in cells if (c["data-method"], c["data-scene"], c["data-weather"], c["data-output"])
                      == ("haze", "scene_a", "rain", "clip_s"))
    assert scene_cell["value"] == "\u2013" and scene_cell["title"] == f"skipped: {reason}"
    mean_cell = next(c for c in cells if c["table"] == "t-paper" and (c["data-method"], c["data-weather"],
                                                                       c["data-output"]) == ("haze", "rain", "clip_s"))
    assert mean_cell["value"] == "\u2013" and reason in mean_cell["title"] and "scene_a" in mean_cell["title"]
    # a null value (not skipped) shows its own reason
    def null_psnr(doc):
        doc["results"]["scene_b"]["clear"]["psnr"].update(value=None, reason="PSNR is infinite for identical images")
    rewrite_results(small["tint"], null_psnr)
    build_report(list(small.values()), out)
    cell = next(c for c in parse_report(out).cells if (c["data-method"], c["data-scene"], c["data-output"])
                == ("tint", "scene_b", "psnr"))
    assert cell["value"] == "\u2013" and "identical images" in cell["title"]


def test_exports_show_the_same_numbers_as_the_html(small, tmp_path):
    out = tmp_path / "r.html"
    outcome = build_report(list(small.values()), out, csv=True, latex=True)
    assert outcome.csv == tmp_path / "r.csv" and outcome.latex == tmp_path / "r.tex"
    html_cells = {(c["table"], c["data-method"], c["data-scene"], c["data-weather"], c["data-output"]): c
                  for c in parse_report(out).cells}
    rows = list(csv.DictReader(outcome.csv.open()))
    assert len(rows) == len(html_cells)
    for r in rows:
        cell = html_cells[(r["table"], r["method"], r["scene"], r["weather"], r["output"])]
        assert (r["value"] or "\u2013") == cell["value"]
        assert (r["rank"] == "best") == (" r1" in cell["class"])
    tex = outcome.latex.read_text()
    assert tex.count(r"\begin{tabular}") == len({k[0] for k in html_cells})
    assert r"\toprule" in tex and r"\midrule" in tex and r"\bottomrule" in tex
    # every number of the HTML appears in the LaTeX, bold exactly where the HTML has the best
    for cell in html_cells.values():
        if cell["value"][:1].isdigit():
            wrapped = rf"\textbf{{{cell['value']}}}" if " r1" in cell["class"] else cell["value"]
            assert wrapped in tex
    numbers_tex = re.findall(r"(?<![\w.])\d+\.\d+", tex)
    numbers_html = [c["value"] for c in html_cells.values() if c["value"][:1].isdigit()]
    assert sorted(numbers_tex) == sorted(numbers_html)


def test_weights_not_published_are_flagged_red_next_to_every_number(small, tmp_path):
    out = tmp_path / "r.html"
    outcome = build_report(list(small.values()), out)
    flagged = {f.topic for f in outcome.flags}
    assert "weights" in flagged
    for cell in _numeric(parse_report(out).cells):
        # the synthetic results record random (unverified) CLIP and SegFormer weights, verified LPIPS
        marked = "\u2020" in cell["markers"]
        assert marked == (cell["data-output"].startswith(("clip", "sem_cs"))), cell
    html = out.read_text()
    assert "mk-weights" in html and "not verified" in html


def test_a_model_whose_every_number_was_skipped_raises_no_weights_flag(small, tmp_path):
    """A fresh install skips CLIP (no weights): the report must not flag numbers that do not exist."""
    def skip_clip(doc):
        for scene, weathers in doc["results"].items():
            for weather in list(weathers):
                for metric in ("clip_s", "clip_ds"):
                    if any(r["metric"] == metric for r in weathers[weather].values()):
                        skip_output(doc, scene, weather, metric, "weights for clip-vit-b32-openai not installed")

    for folder in small.values():
        rewrite_results(folder, skip_clip)
    outcome = build_report(list(small.values()), tmp_path / "r.html")
    flags = [f for f in outcome.flags if f.topic == "weights"]
    assert flags and not any("clip" in f.message.lower() for f in flags)  # SegFormer's numbers still flagged
    assert all("sem_cs" in f.message for f in flags)


def test_mismatched_folders_are_flagged_not_mixed(small, tmp_path):
    def other_frames_and_size(doc):
        for weathers in doc["inputs"]["scenes"].values():
            for rec in weathers.values():
                rec["source"] = rec["source"][:-1]
        for files in doc["inputs"]["files"].values():
            files["size"] = [128, 72]
        for weathers in doc["results"].values():
            for outputs in weathers.values():
                outputs["temporal_flicker"]["variant"] = "another definition"
                outputs["fps"]["extra"]["resolution"] = [128, 72]
        doc["config"]["metric_config"]["temporal_flicker"]["config"] = {"color": "luma"}

    rewrite_results(small["grain"], other_frames_and_size)
    out = tmp_path / "r.html"
    outcome = build_report(list(small.values()), out)
    topics = {f.topic for f in outcome.flags}
    assert {"frames", "resolution", "variant", "settings"} <= topics
    html = out.read_text()
    assert "frame counts differ" in html and "frame sizes differ" in html and "different definitions" in html
    cells = _numeric(parse_report(out).cells)
    flicker = [c for c in cells if c["data-output"] == "temporal_flicker"]
    assert flicker and all("\u2021" in c["markers"] for c in flicker)


def test_methods_scored_at_different_sizes_are_one_line_naming_them(small, tmp_path, capsys):
    """Results of an earlier wcbench scored a method at its own render size: the report says so in
    one line naming the methods and sizes (not one box per metric repeating every definition), in
    the HTML and on the console, and marks the numbers it touches."""
    def scored_smaller(doc):
        for weathers in doc["results"].values():
            for outputs in weathers.values():
                for name, r in outputs.items():
                    if name != "fps":  # FPS reads no frames: no size scored at
                        r["variant"] += "; scored at 32x18"

    rewrite_results(small["grain"], scored_smaller)
    out = tmp_path / "r.html"
    assert main(["report", *map(str, small.values()), "--out", str(out)]) == 0
    expected = "scored at different sizes: grain 32x18; haze, tint 64x36 (on scene_a, scene_b)"
    printed = [line for line in capsys.readouterr().out.splitlines()
               if line.startswith("  flagged") and "(weights)" not in line]
    assert len(printed) == 1 and printed[0].startswith(f"  flagged (size): {expected} ("), printed
    page = out.read_text()
    assert page.count('<li class="mismatch">') == 1 and expected in html.unescape(page)
    assert "different definitions" not in page
    cells = _numeric(parse_report(out).cells)
    read = [c for c in cells if c["data-output"] != "fps"]
    assert read and all("\u2021" in c["markers"] for c in read)
    assert not any("\u2021" in c["markers"] for c in cells if c["data-output"] == "fps")


def test_a_size_mixed_on_one_scene_marks_that_scene_and_the_means(small, tmp_path):
    def scene_a_smaller(doc):
        for outputs in doc["results"]["scene_a"].values():
            for name, r in outputs.items():
                if name != "fps":
                    r["variant"] += "; scored at 32x18"

    rewrite_results(small["grain"], scene_a_smaller)
    out = tmp_path / "r.html"
    outcome = build_report(list(small.values()), out)
    [flag] = [f for f in outcome.flags if f.kind == "mismatch"]
    assert flag.message.startswith("scored at different sizes: grain 32x18; haze, tint 64x36 (on scene_a) (")
    cells = [c for c in _numeric(parse_report(out).cells) if c["data-output"] == "psnr"]
    marked = {(c["data-method"], c["data-scene"]) for c in cells if "\u2021" in c["markers"]}
    assert marked == {(m, s) for m in small for s in ("scene_a", "mean")}


def test_fps_at_each_methods_own_render_size_is_shown_not_flagged(small, tmp_path):
    """FPS is a method's speed at the size it renders at (the runtime table gives it); only one
    method's FPS measured at several sizes, mixed in its means, is flagged."""
    def render_larger(doc):
        for weathers in doc["results"].values():
            for outputs in weathers.values():
                outputs["fps"]["extra"]["resolution"] = [128, 72]

    rewrite_results(small["grain"], render_larger)
    outcome = build_report(list(small.values()), tmp_path / "r.html")
    assert not [f for f in outcome.flags if f.kind == "mismatch"]
    assert "128x72" in (tmp_path / "r.html").read_text()
    # one method's FPS of one scene at two sizes (another tool's info.json per weather): its means mix them
    def fog_larger(doc):
        doc["results"]["scene_a"]["fog"]["fps"]["extra"]["resolution"] = [128, 72]

    rewrite_results(small["tint"], fog_larger)
    outcome = build_report(list(small.values()), tmp_path / "r2.html")
    [flag] = [f for f in outcome.flags if f.kind == "mismatch"]
    assert flag.topic == "resolution" and "(tint on scene_a: 128x72, 64x36)" in flag.message
    assert flag.outputs == {"fps"} and flag.units == {("tint", "scene_a", "fps")}


def test_scene_sets_that_differ_are_flagged_on_the_means(small, tmp_path):
    def drop_scene_b(doc):
        for key in ("results",):
            doc[key].pop("scene_b")
        doc["inputs"]["scenes"].pop("scene_b")
        doc["skipped"] = [s for s in doc["skipped"] if s["scene"] != "scene_b"]

    rewrite_results(small["haze"], drop_scene_b)
    out = tmp_path / "r.html"
    outcome = build_report(list(small.values()), out)
    flag = next(f for f in outcome.flags if f.topic == "scenes")
    assert "haze" in flag.message and "scene_b" in flag.message
    cells = _numeric(parse_report(out).cells)
    means = [c for c in cells if c["data-method"] == "haze" and c["data-scene"] == "mean"]
    per_scene = [c for c in cells if c["data-method"] == "haze" and c["data-scene"] == "scene_a"]
    assert means and all("\u2021" in c["markers"] for c in means)
    assert per_scene and not any("\u2021" in c["markers"] for c in per_scene)
    missing = next(c for c in parse_report(out).cells if (c["data-method"], c["data-scene"]) == ("haze", "scene_b"))
    assert missing["value"] == "\u2013" and "not scored" in missing["title"]


def test_same_method_in_two_folders_on_the_same_scenes_stays_two_rows(small, tmp_path):
    twin = tmp_path / "tint_again"
    shutil.copytree(small["tint"], twin)
    out = tmp_path / "r.html"
    outcome = build_report([small["tint"], twin], out)
    methods = {c["data-method"] for c in parse_report(out).cells}
    assert methods == {"tint (tint)", "tint (tint_again)"}
    assert any(f.topic == "duplicate" for f in outcome.flags)


def test_frames_are_shown_only_when_their_hash_matches(small, tmp_path):
    out = tmp_path / "r.html"
    build_report([small["tint"]], out, animation_frames=3)
    images = parse_report(out).images
    assert images and all(src.startswith("data:image/") for src in images)
    assert any(src.startswith(("data:image/webp", "data:image/gif")) for src in images)
    # replace one shown frame: it is no longer the scored one
    frame = small["tint"] / "tint" / "scene_a" / "rain" / "002.png"
    shutil.copy(small["tint"] / "tint" / "scene_a" / "rain" / "000.png", frame)
    build_report([small["tint"]], out, animation_frames=3)
    assert "002.png changed since it was scored" in out.read_text()
    assert len(parse_report(out).images) < len(images)


def test_moved_results_folder_still_finds_its_frames(small, tmp_path):
    moved = tmp_path / "elsewhere" / "copy"
    shutil.copytree(small["haze"], moved)
    shutil.rmtree(small["haze"])
    out = tmp_path / "r.html"
    build_report([moved], out, animation_frames=2)
    text = out.read_text()
    assert "not found" not in text and "changed since" not in text


def test_same_inputs_give_the_same_report_except_the_date(small, tmp_path):
    a, b = tmp_path / "a.html", tmp_path / "b.html"
    build_report(list(small.values()), a, animation_frames=3)
    build_report(list(small.values()), b, animation_frames=3)
    date = re.compile(r"Built \S+ ")
    assert date.sub("", a.read_text()) == date.sub("", b.read_text())


def test_benchmark_files_are_charted_with_the_default_marked(small, tmp_path):
    from wcbench.bench.schema import BenchCase, BenchReport

    bench = BenchReport("demo")
    for value, ms, err in ((1, 10.0, 0.1), (2, 20.0, 0.01), (4, 45.0, 0.001)):
        bench.cases.append(BenchCase(f"c{value}", "threads", value, ms, err, "abs", extra={"default": value == 2}))
    bench.write(tmp_path / "b.json")
    out = tmp_path / "r.html"
    outcome = build_report([small["tint"]], out, bench=[tmp_path / "b.json"], frames=False)
    text = out.read_text()
    assert "knob: threads (default 2)" in text
    assert outcome.n_images >= 2  # per-frame curves + the chart
    (tmp_path / "bad.json").write_text(json.dumps({"schema": "other"}))
    from wcbench.core.errors import InputError

    with pytest.raises(InputError, match=r"bad\.json: not a wcbench-benchmark v1 file"):
        build_report([small["tint"]], out, bench=[tmp_path / "bad.json"])


def test_real_run_with_report_flag_writes_a_report_beside_results(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "--method", "filter2d", "--scenes", "demo", "--out", str(out), "--weathers", "rain",
                 "clear", "--metrics", "temporal_flicker", "psnr", "fps", "--no-progress", "--report"]) == 0
    assert "report.html" in capsys.readouterr().out
    files = json.loads((out / "results.json").read_text())["inputs"]["files"]["demo"]
    assert files["weathers"]["rain"]["predictions"][0] == "filter2d/demo/rain/000.png"  # inside: relative
    assert Path(files["source"][0]).is_absolute() and files["size"] == [320, 180]
    parsed = parse_report(out / "report.html")
    values = result_values([out])
    numeric = _numeric(parsed.cells)
    assert numeric
    for cell in numeric:
        assert cell["value"] == expected_text(values, cell, len(cell["value"].split(".")[1]))
    # raw frame, filter2d frame, and an animation of each, for both weathers
    assert sum(src.startswith("data:image/jpeg") for src in parsed.images) == 4
    assert sum(src.startswith(("data:image/webp", "data:image/gif")) for src in parsed.images) == 4
    assert "weights" not in {f for f in re.findall(r"flagged \((\w+)\)", capsys.readouterr().out)}


def test_the_readme_report_example_gives_a_report_without_a_flag(tmp_path, capsys):
    """The report example of docs/guide.md (identity, filter2d and lidar-init run separately on one scene,
    then one report) on the demo scene: lidar-init renders at a quarter of the scene's size, yet all
    three are scored at the scene's working size, so nothing differs and nothing is flagged."""
    pytest.importorskip("torch")  # lidar-init is a reference-model method
    runs = tmp_path / "runs"
    for method in ("identity", "filter2d", "lidar-init"):
        assert main(["run", "--method", method, "--scenes", "demo", "--out", str(runs / method), "--weathers",
                     "clear,rain", "--frames", "0-3", "--metrics", "psnr", "ssim", "temporal_flicker",
                     "flow_warping_error", "fps", "--no-progress"]) == 0
    capsys.readouterr()
    out = tmp_path / "report.html"
    assert main(["report", *(str(runs / m) for m in ("identity", "filter2d", "lidar-init")), "--out", str(out),
                 "--csv", "--latex"]) == 0
    printed = capsys.readouterr().out
    assert "flagged" not in printed, printed
    page = out.read_text()
    assert '<ul class="flags">' not in page and "No mismatch across results folders" in page
    cells = _numeric(parse_report(out).cells)
    assert {c["data-method"] for c in cells} == {"identity", "filter2d", "lidar-init"}
    assert not any(c["markers"] for c in cells)
    assert "\\ddag" not in out.with_suffix(".tex").read_text().split("\n\n", 1)[1]
    lidar = json.loads((runs / "lidar-init" / "results.json").read_text())
    [record] = [r for r in lidar["working_size"] if r["weather"] == "rain"]
    assert (record["predictions"], record["to"], record["predictions_resized"]) == ([80, 45], [320, 180], True)
    # said as a fact, not a flag
    assert "demo (320x180 frames) scored at 320x180; lidar-init's 80x45 frames resized to it." \
        in html.unescape(page)
    # FPS stays the method's own: measured at the size it renders at, shown in the runtime table
    assert lidar["results"]["demo"]["rain"]["fps"]["extra"]["resolution"] == [80, 45]
    assert "<td>80x45</td>" in page


def test_report_cli_from_outside_the_source_tree(small, tmp_path):
    """As a user would: the console entry point, relative paths, exports beside the HTML."""
    res = subprocess.run([sys.executable, "-m", "wcbench", "report", "tint", "haze", "--out", "out/report.html",
                          "--csv", "--latex", "--animation-frames", "2"], cwd=tmp_path, capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stderr
    assert "wrote out/report.html" in res.stdout
    assert {p.name for p in (tmp_path / "out").iterdir()} == {"report.html", "report.csv", "report.tex"}


def test_training_time_of_a_scene_counts_once_across_its_weathers(small, tmp_path):
    # one model per scene serves every weather: each weather's info.json repeats the scene's time
    for scene, seconds in (("scene_a", 100.0), ("scene_b", 50.0)):
        for info_path in (small["tint"] / "tint" / scene).glob("*/info.json"):
            info = json.loads(info_path.read_text())
            info.setdefault("timings", {})["train_s"] = seconds
            info_path.write_text(json.dumps(info))
    out = tmp_path / "r.html"
    build_report([small["tint"]], out, animation_frames=0)
    html = out.read_text()
    assert "150.0 s" in html and "450.0 s" not in html


def test_the_papers_summary_columns_follow_its_rule_in_html_csv_and_latex(tmp_path):
    """CLIP-DS averaged over rain, snow and fog; CLIP-S and Sem-CS over rain and snow; from the cells."""
    from wcbench.bench.report import make_results_folders

    root = tmp_path / "res"
    make_results_folders(root, methods=("tint", "haze"), scenes=("scene_a", "scene_b"),
                         weathers=("clear", "rain", "snow", "fog"), n_frames=4, size=(64, 36))
    folders = sorted(p for p in root.iterdir() if (p / "results.json").is_file())
    # one scene of haze lost its snow CLIP-S: haze's CLIP-S summary is a dash naming the weather
    rewrite_results(root / "haze", lambda doc: skip_output(doc, "scene_b", "snow", "clip_s", "weights missing"))
    out = tmp_path / "r.html"
    build_report(folders, out, csv=True, latex=True)
    values = result_values(folders)
    summary = [c for c in parse_report(out).cells if c["data-weather"] == "mean (paper's rule)"]
    assert {c["data-output"] for c in summary} == {"clip_s", "clip_ds", "sem_cs"}
    rule = {"clip_ds": ("rain", "snow", "fog"), "clip_s": ("rain", "snow"), "sem_cs": ("rain", "snow")}
    for cell in summary:
        method, output = cell["data-method"], cell["data-output"]
        per_weather = [np.mean([values[(method, s, w, output)] for s in ("scene_a", "scene_b")])
                       if all(values.get((method, s, w, output)) is not None for s in ("scene_a", "scene_b"))
                       else None for w in rule[output]]
        if None in per_weather:
            assert (method, output) == ("haze", "clip_s") and cell["value"] == "\u2013"
            assert "no number in snow" in cell["title"]
        else:
            assert cell["value"] == f"{np.mean(per_weather):.3f}", cell
    page = html.unescape(out.read_text())
    assert "by the paper's rule: CLIP-DS over rain, snow and fog; CLIP-S and Sem-CS over rain and snow" in page
    rows = list(csv.DictReader(io.StringIO((tmp_path / "r.csv").read_text())))
    in_csv = {(r["method"], r["output"]): r["value"] or "\u2013" for r in rows
              if r["weather"] == "mean (paper's rule)" and r["table"] == "t-paper"}
    assert in_csv == {(c["data-method"], c["data-output"]): c["value"] for c in summary}
    assert "mean (paper's rule)" in (tmp_path / "r.tex").read_text()


def _with_truth(doc, *, method_psnr, raw_psnr):
    """Give every scene a rain ground truth: the method's PSNR there and the raw frames' against it."""
    doc["raw_frames"] = {}
    for scene, weathers in doc["results"].items():
        if "rain" in weathers:
            weathers["rain"]["psnr"] = {"metric": "psnr", "value": method_psnr, "variant": "", "reason": "",
                                        "higher_is_better": True, "per_frame": [], "extra": {}}
            doc["raw_frames"].setdefault(scene, {})["rain"] = {
                "psnr": {"metric": "psnr", "value": raw_psnr, "variant": "", "reason": "", "higher_is_better": True}}


def _row(table, method):
    return next(r for r in table.rows if r.method == method)


def test_skipped_metrics_are_listed_with_their_reasons_beside_the_tables(small, tmp_path):
    reason = "weights not installed: clip-vit-b32 (wcbench models fetch clip-vit-b32)"
    for folder in small.values():
        def skip_everywhere(doc):
            for scene, weathers in list(doc["results"].items()):
                for weather in list(weathers):
                    if any(r["metric"] == "clip_s" for r in weathers[weather].values()):
                        skip_output(doc, scene, weather, "clip_s", reason)
        rewrite_results(folder, skip_everywhere)
    out = tmp_path / "r.html"
    build_report(list(small.values()), out, frames=False)
    text = out.read_text()
    block = re.search(r'<div class="skipped" id="skipped">(.*?)</div>', text, re.S)
    assert block is not None, "no list of skipped metrics"
    assert "<strong>CLIP-S</strong>: " + html.escape(reason) in block.group(1)
    # where the tables are, and the checks say it rather than only "verified"
    assert text.index('id="skipped"') > text.index('id="tables"')
    assert re.search(r'class="skipped-note">Not computed: [^<]*CLIP-S', text)


def test_ground_truth_table_has_a_raw_frames_row_that_is_never_marked(small, tmp_path):
    for i, folder in enumerate(small.values()):
        rewrite_results(folder, lambda d, i=i: _with_truth(d, method_psnr=20.0 + i, raw_psnr=31.25))
    out = tmp_path / "r.html"
    outcome = build_report(list(small.values()), out, frames=False, csv=True)
    table = next(t for t in outcome.tables if t.id == "t-reference")
    raw = _row(table, RAW_FRAMES)
    assert raw.baseline
    j = next(j for j, c in enumerate(table.columns) if (c.weather, c.output) == ("rain", "psnr"))
    assert raw.cells[j].text == "31.25" and raw.cells[j].rank == 0  # the highest PSNR, yet not bold
    assert [r.cells[j].rank for r in table.rows if r.method != RAW_FRAMES].count(1) == 1
    clear = next(j for j, c in enumerate(table.columns) if c.weather == "clear")
    assert raw.cells[clear].value is None and "raw frames themselves" in raw.cells[clear].reason
    scene_table = next(t for t in outcome.tables if t.id == "s-reference")
    assert [r.scene for r in scene_table.rows if r.method == RAW_FRAMES] == ["scene_a", "scene_b"]
    assert f'data-method="{RAW_FRAMES}"' in out.read_text()
    assert RAW_FRAMES in out.with_suffix(".csv").read_text()


def test_identity_rows_are_yardsticks_and_bold_goes_to_a_real_method(small, tmp_path):
    def as_identity(doc):
        doc["config"]["method"] = "identity"
        for weathers in doc["results"].values():
            for outputs in weathers.values():
                for r in outputs.values():  # the best number of every column
                    if r["value"] is not None:
                        r["value"] = 1e3 if r["higher_is_better"] else -1e3
    rewrite_results(small["tint"], as_identity)
    outcome = build_report(list(small.values()), tmp_path / "r.html", frames=False)
    table = next(t for t in outcome.tables if t.id == "t-paper")
    identity = _row(table, "identity")
    assert identity.baseline and all(c.rank == 0 for c in identity.cells)
    for j in range(len(table.columns)):
        ranked = [r.cells[j].rank for r in table.rows if r.method != "identity"]
        if sum(r.cells[j].value is not None for r in table.rows if r.method != "identity") >= 2:
            assert 1 in ranked, table.columns[j]
