"""Train the WeatherCity model of each scene, without rendering or evaluating.

The trained model goes to the cache (keyed by the scene, the settings and the supervision), where
`wcbench run --method weathercity` with the same options finds it; a killed training resumes from
its last checkpoint. What was built, skipped and measured (time, Gaussians per node, held-out PSNR)
is printed and written to OUT/<scene>/training.json.

Examples::

    wcbench train --scenes demo --profile quick --out runs/train
    wcbench train --scenes pandaset_002 --data-root ../shared/data --holdout 5,15,25 --out runs/train
    wcbench train --scenes pandaset_002 --data-root ../shared/data --ablation no-wgs --setting iterations=500
    wcbench train --scenes pandaset_002 --data-root ../shared/data --supervision qwen-image:edits/
"""

from __future__ import annotations

import argparse
from pathlib import Path

from wcbench.cli.common import (
    add_offline_argument,
    add_progress_argument,
    add_scene_arguments,
    parse_key_values,
    split_list,
)
from wcbench.core.errors import InputError

HELP = "train the weathercity model of each scene (cached for `run`)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``wcbench train``."""
    add_scene_arguments(parser)
    parser.add_argument("--out", type=Path, default=Path("runs/train"),
                        help="where OUT/<scene>/training.json goes (default: runs/train)")
    parser.add_argument("--profile", default="default", help="training profile: default, quick")
    parser.add_argument("--ablation", default="", help="named ablation: no-wgs, no-content-loss")
    parser.add_argument("--supervision", default="physical-editor",
                        help="edited frames to learn from: physical-editor (built in, the default), filter2d "
                             "(built in), sim-editor[:SEVERITY] (needs ground-truth scenes, e.g. synth_1) or "
                             "READER:DIR")
    parser.add_argument("--jitter", type=float, default=0.0,
                        help="per-frame perturbation of the filter2d supervision, 0..1 (default 0)")
    parser.add_argument("--holdout", nargs="*", default=None, metavar="FRAME",
                        help="frames left out of training and scored (e.g. 5,15,25)")
    parser.add_argument("--setting", action="append", default=[], metavar="KEY=VALUE",
                        help="training setting overriding the profile, repeatable (VALUE as JSON), "
                             "e.g. iterations=500, budget=200000")
    parser.add_argument("--checkpoint", type=Path, default=None,
                        help="checkpoint folder (one scene only; default: the cache, keyed by the inputs)")
    add_offline_argument(parser)
    add_progress_argument(parser)


def run(args: argparse.Namespace) -> int:
    """Train every scene of the set; print and write what each training measured."""
    from wcbench.core.models.fetch import fetch_missing, is_offline
    from wcbench.core.storage import atomic_write_json, check_writable_folder
    from wcbench.methods.weather_spec import resolve_physics
    from wcbench.methods.weathercity import train_scene
    from wcbench.reference_model.training.config import make_config
    from wcbench.scenes.sets import resolve_scenes

    try:
        holdout = tuple(int(h) for h in (split_list(args.holdout) or []))
        settings = parse_key_values(args.setting, option="--setting", example="iterations=500")
        config = make_config(args.profile, ablation=args.ablation, holdout=holdout, **settings)
    except ValueError as exc:
        raise InputError(f"train: {exc}") from None
    if not 0.0 <= args.jitter <= 1.0:
        raise InputError(f"--jitter must be in [0, 1], got {args.jitter}")
    if args.out is not None:
        check_writable_folder(args.out)
    refs = resolve_scenes(args.scenes, data_root=args.data_root)
    if args.checkpoint is not None and len(refs) > 1:
        raise InputError(f"--checkpoint names one folder, but {args.scenes} has {len(refs)} scenes")
    # the content loss's VGG16, fetched before the first scene trains (skipped with the reason if it stays missing)
    models = fetch_missing(["vgg16"] if config.content_weight != 0 else [], offline=is_offline(args.offline))
    for ref in refs:
        scene = ref.load()
        bad = [h for h in holdout if not 0 <= h < len(scene)]
        if bad:
            raise InputError(f"--holdout {bad}: {scene.id} has frames 0..{len(scene) - 1}")
        # the physics `run --method weathercity` renders with by default, so that it finds this model
        _, _, facts = train_scene(scene, config, supervision=args.supervision, jitter=args.jitter,
                                  physics=resolve_physics(scene, "auto"), folder=args.checkpoint,
                                  show_progress=not args.no_progress)
        path = args.out / scene.id / "training.json"
        atomic_write_json(path, {**facts, "models": {name: o.record() for name, o in models.items()}})
        counts = facts["gaussians"]
        line = (f"{scene.id}: {facts['iterations']} steps in {facts['train_seconds']:.1f} s, "
                f"{counts['total']} Gaussians ({counts['background']} background, {counts['rigid']} in "
                f"{counts['rigid_nodes']} rigid, {counts['nonrigid']} in {counts['nonrigid_nodes']} non-rigid)")
        if "holdout" in facts:
            line += f"; held-out PSNR {facts['holdout']['mean_psnr']:.2f} dB"
        print(line)
        print(f"  checkpoint {facts['checkpoint']}\n  facts {path}")
    return 0
