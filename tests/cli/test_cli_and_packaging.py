"""The command line stays light, every folder ships in the wheel, and the wheel imports."""

from __future__ import annotations

import subprocess
import sys
import zipfile

import pytest
from paths import REPO

from wcbench.cli import COMMANDS, main

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def test_help_imports_neither_torch_nor_onnxruntime():
    code = ("import sys; from wcbench.cli import build_parser; build_parser().format_help(); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'onnxruntime', 'cv2', 'pandas', "
            "'matplotlib', 'PIL', 'jinja2')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=REPO.parent).stdout
    assert out.strip() == "[]"


def test_every_verb_has_help_and_docs(capsys):
    assert set(COMMANDS) == {"run", "evaluate", "render", "train", "scenes", "methods", "metrics", "models", "report",
                             "bench", "compile"}
    for verb in COMMANDS:
        with pytest.raises(SystemExit) as exc:
            main([verb, "--help"])
        assert exc.value.code == 0
        assert "usage: wcbench" in capsys.readouterr().out


def test_python_dash_m_entry_point():
    out = subprocess.run([sys.executable, "-m", "wcbench", "--version"], capture_output=True, text=True, check=True,
                         cwd=REPO.parent)
    assert out.stdout.startswith("wcbench ")


def test_the_checkout_imports_like_the_installed_package():
    """From the repository root `./wcbench` shadows the installed package; its three sibling folders
    must still import as wcbench.metrics, wcbench.reports and wcbench.reference_model."""
    code = ("import wcbench, wcbench.metrics, wcbench.reports, wcbench.reference_model, wcbench.metrics.temporal; "
            "print(wcbench.__file__); print(wcbench.metrics.__file__)")
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    package, metrics = done.stdout.split()
    # whichever package Python picked, the metrics came from the same tree
    assert (REPO / "wcbench" / "__init__.py").samefile(package)
    assert (REPO / "metrics" / "__init__.py").samefile(metrics)


def test_listing_commands(capsys):
    assert main(["scenes", "list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in ("waymo_5", "nuscenes_5", "pandaset_002", "demo"))
    assert main(["methods", "list"]) == 0
    out = capsys.readouterr().out
    for name in ("controlnet", "turboedit", "fresco", "qwen-image", "climatenerf", "folder", "identity", "filter2d"):
        assert name in out
    assert main(["metrics", "list"]) == 0
    assert "ssim" in capsys.readouterr().out
    assert main(["models", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split() == ["name", "kind", "state", "source", "description"]  # a header under the store line
    assert any(line.startswith("clip-bpe-vocab") for line in lines[2:])


def test_scenes_show_real_scene(pandaset_root, capsys):
    assert main(["scenes", "show", str(pandaset_root)]) == 0
    out = capsys.readouterr().out
    assert "30 frames 1920x1080" in out and "27/30 frames" in out


def test_packages_in_pyproject_cover_every_folder():
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    mapping = config["package-dir"]
    listed = set(config["packages"])
    found = set()
    for pkg, folder in mapping.items():
        for init in (REPO / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(REPO / folder)
            found.add(".".join([pkg, *rel.parts]))
    assert found == listed, f"missing from pyproject packages: {found - listed}; stale: {listed - found}"


@pytest.mark.slow
def test_built_wheel_installs_and_imports(tmp_path):
    """Build the wheel, install it into a clean folder and import from there, not from the tree."""
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w",
                    str(tmp_path / "dist"), str(REPO)], check=True, capture_output=True)
    wheel = next((tmp_path / "dist").glob("wcbench-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    for expected in ("wcbench/metrics/pixel/ssim.py", "wcbench/scenes/specs/waymo_5.toml",
                     "wcbench/methods/presets/controlnet.toml", "wcbench/reports/__init__.py",
                     "wcbench/metrics/models.toml", "wcbench/reference_model/models.toml",
                     "wcbench/reference_model/weather/presets.toml", "wcbench/metrics/clip/weather_prompts.toml",
                     "wcbench/reports/templates/report.html.j2", "wcbench/reports/display.toml",
                     "wcbench/bench/report.py"):
        assert expected in names
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--target", str(target), str(wheel)],
                   check=True, capture_output=True)
    code = ("import wcbench.metrics, wcbench.scenes.sets, wcbench.methods, wcbench.core.models.store as s; "
            "print(wcbench.metrics.__file__); print(len(wcbench.scenes.sets.list_scene_sets())); "
            "print(len(s.ModelStore().entries))")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(target), "PATH": ""}).stdout.split()
    # the catalogues of both libraries are found through the wheel's entry points
    assert out[0].startswith(str(target)) and int(out[1]) >= 4 and int(out[2]) == 19


def test_evaluation_side_runs_without_torch(tmp_path):
    """Scoring frames imports neither torch nor onnxruntime unless a model metric asks for it."""
    code = (
        "import sys, wcbench.cli as c; "
        f"c.main(['run', '--method', 'filter2d', '--scenes', 'demo', '--out', r'{tmp_path / 'o'}', "
        "'--weathers', 'rain', '--no-progress']); "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'numba', 'onnxruntime'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=tmp_path).stdout
    assert out.strip().splitlines()[-1] == "[]"
