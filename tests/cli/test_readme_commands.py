"""Every command of the README, verbatim, in a fresh virtual environment (slow: installs the package).

The README's ``bash`` blocks are read; each ``wcbench`` / ``pip`` command must be listed below as run
or as not runnable here (with the reason), so a new README command cannot go untested unnoticed.
The run ones execute in order in a clean clone's fresh venv, from a folder outside the source
tree whose ``../shared/data`` is the real scene (as in the README).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from paths import PANDASET, REPO

#: Commands needing what this machine does not have (the README shows them for real datasets).
NOT_HERE = {
    "pip install tox && tox -e py311,lint": "the test suite itself",
    "pip install -e \".[model,test,lint]\"": "the developer install (the test environment is one)",
}
NOT_HERE_PATTERNS = {
    r"waymo_5|nuscenes_5|(?<![\w.])/data\b|(?<!\.)/shared/data|HOST": "needs datasets or a cluster this machine lacks",
    r"--predictions (my_frames|cn_out|controlnet_out|fresco_rain)/": "needs another tool's outputs",
    r"--scenes pandaset_002 --data-root \.\./shared/data --out runs/wc\b|--out runs/wc-(edit|insert)\b"
    r"|--out runs/train\b":
        "trains the default profile (about 7 minutes each; the insertion two scenes): measured by `wcbench bench "
        "model` and `bench streets` instead",
    r"^wcbench bench (--all|all|model|metrics|raster|weather|report|scale|validity|streets)\b":
        "benchmarks (measured, not smoke-tested)",
    r"^wcbench models pull|^wcbench models import": "downloads weights or needs a checkpoint file",
    r"^wcbench report runs/identity": "needs the three pandaset runs of the report section",
    r"--out runs/(identity|filter2d|lidar[_-]init)$": "the report section's 1080p runs (`run --method identity "
        "--scenes pandaset_002 ... --weathers clear` stands for them)",
}


def readme_commands(text: str) -> list[str]:
    """The ``wcbench`` and ``pip`` commands of the README's ``bash`` blocks, continuation lines joined."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            line = re.sub(r"\s+", " ", line)
            if line.startswith(("wcbench ", "pip ")):
                out.append(line)
    return out


def why_not_here(cmd: str) -> str | None:
    if cmd in NOT_HERE:
        return NOT_HERE[cmd]
    for pattern, why in NOT_HERE_PATTERNS.items():
        if re.search(pattern, cmd):
            return why
    return None


def test_every_readme_command_is_classified() -> None:
    cmds = readme_commands((REPO / "README.md").read_text())
    assert cmds[0].startswith('pip install ".[model]" && wcbench run')  # the set-up line comes first
    runnable = [c for c in cmds if why_not_here(c) is None]
    assert len(runnable) >= 8, runnable  # the README keeps a good part of its commands runnable here


@pytest.mark.slow
def test_readme_commands_work_verbatim_in_a_fresh_venv(tmp_path: Path) -> None:
    if not (PANDASET / "images").is_dir():
        pytest.skip(f"real scene not present at {PANDASET}")
    python = shutil.which("python3.11")
    if python is None:
        pytest.skip("python3.11 not found (the [model] extra needs it)")
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True)
    venv = tmp_path / "venv"
    subprocess.run([python, "-m", "venv", str(venv)], check=True)
    work = tmp_path / "user" / "work"  # outside the source tree; ../shared/data is the real data
    work.mkdir(parents=True)
    (tmp_path / "user" / "shared").mkdir()
    (tmp_path / "user" / "shared" / "data").symlink_to(PANDASET.parent, target_is_directory=True)
    env = {**os.environ, "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}", "VIRTUAL_ENV": str(venv),
           "WCBENCH_CACHE": str(tmp_path / "cache"), "WCBENCH_MODELS": str(tmp_path / "models")}
    env.pop("PYTHONPATH", None)
    env.pop("WCBENCH_BACKGROUND_COMPILE", None)  # as a user's first run: the kernels compile beside it
    cmds = readme_commands((clone / "README.md").read_text())
    ran = []
    for cmd in cmds:
        if why_not_here(cmd) is not None:
            continue
        cwd = clone if cmd.startswith("pip ") else work  # `pip install ".[model]"` names the clone
        if cmd.startswith("pip ") and "&&" in cmd:  # the set-up line: install in the clone, run outside
            install, main_job = (part.strip() for part in cmd.split("&&", 1))
            steps = [(install, clone), (main_job, work)]
        else:
            steps = [(cmd, cwd)]
        for step, where in steps:
            start = time.perf_counter()
            proc = subprocess.run(shlex.split(step), cwd=where, env=env, capture_output=True, text=True)
            assert proc.returncode == 0, f"{step!r} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n" \
                                         f"{proc.stderr[-3000:]}"
            ran.append((step, time.perf_counter() - start))
    assert any(r.startswith("wcbench run --method filter2d --scenes demo") for r, _ in ran)
    assert (work / "runs" / "demo" / "results.json").is_file()
    # what each command took (shown with -s): the test's time is CI's largest single cost
    print(f"{len(ran)} README commands ran:", *(f"{t:7.1f} s  {r}" for r, t in ran), sep="\n", file=sys.stderr)
