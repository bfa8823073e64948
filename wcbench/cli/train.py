"""Train the WeatherCity model of each scene, without rendering or evaluating.

The trained model goes to the cache (keyed by the scene's data, the settings and the supervision), where
`wcbench run --method weathercity` with the same options finds it; a killed training resumes from
its last checkpoint. A second process asking for a model being trained waits for it, then loads
it. What was built, skipped and measured (time, Gaussians per node, held-out PSNR) is printed and
written to OUT/<scene>/training.json.

Examples::

    wcbench train --scenes demo --profile quick --out runs/train
    wcbench train --scenes pandaset_002 --data-root ../shared/data --holdout 5,15,25 --out runs/train
    wcbench train --scenes pandaset_002 --data-root ../shared/data --ablation no-wgs \\
        --method-option settings.iterations=500
    wcbench train --scenes pandaset_002 --data-root ../shared/data --supervision qwen-image:edits/

``train`` takes the method options of ``wcbench run --method weathercity`` spelled alike
(``--profile``, ``--supervision``, ``--jitter``, ``--ablation``, ``--holdout`` and
``--method-option KEY=VALUE``), so that ``run`` with the same options finds the trained model.
Options that only concern rendering (``edits``, ``size``) are refused. ``--setting KEY=VALUE`` is
the deprecated spelling of ``--method-option settings.KEY=VALUE``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from wcbench.cli.common import (
    add_deprecated_alias,
    add_method_options,
    add_offline_argument,
    add_output_argument,
    add_progress_argument,
    add_scene_arguments,
    checked_method_options,
    method_options_from,
)
from wcbench.core.errors import InputError

HELP = "train the weathercity model of each scene (cached for `run`)"

#: The method options of weathercity that concern training (the others, edits and size, only rendering).
TRAINING_OPTIONS = ("ablation", "device", "holdout", "jitter", "physics", "profile", "settings", "supervision")


def training_options(args: argparse.Namespace) -> dict[str, Any]:
    """The weathercity method options ``args`` give, read as ``run`` reads them and checked as its
    constructor's (``holdout`` as a tuple of ints).

    Raises
    ------
    InputError
        On an option that only concerns rendering; ``OptionError`` on a value weathercity's declared
        option does not allow (:func:`wcbench.methods.validate_method_options`).
    """
    from wcbench.methods import renamed_method_options

    options = method_options_from(args)
    renamed = renamed_method_options("weathercity")  # an old name (weathers) is its new one's (physics)
    other = sorted(key for key in options if renamed.get(key, key) not in TRAINING_OPTIONS)
    if other:
        raise InputError(f"train: method option {', '.join(other)} concerns rendering, not training (give it to "
                         f"`wcbench run` or `wcbench render`); train takes {', '.join(TRAINING_OPTIONS)}")
    # weathercity's declared options (types, ranges, settings.*), checked before any scene is read
    return checked_method_options(args, "weathercity", options)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``wcbench train``."""
    add_scene_arguments(parser)
    add_output_argument(parser, default=Path("runs/train"),
                        help="where OUT/<scene>/training.json goes (default: runs/train)")
    group = add_method_options(parser, edit=False)
    add_deprecated_alias(group, "--setting", use="--method-option settings.KEY=VALUE", dest="setting",
                         metavar="KEY=VALUE", append=True, help="a training setting overriding the profile")
    parser.add_argument("--checkpoint", type=Path, default=None,
                        help="checkpoint folder (one scene only; default: the cache, keyed by the inputs)")
    add_offline_argument(parser)
    add_progress_argument(parser)


def run(args: argparse.Namespace) -> int:
    """Train every scene of the set; print and write what each training measured."""
    from wcbench.core.models.fetch import fetch_missing, is_offline
    from wcbench.core.storage import atomic_write_json, check_writable_folder
    from wcbench.execution.background_compile import kernels_compiled_aside
    from wcbench.methods.scene_training import check_supervision, train_scene
    from wcbench.methods.weather_spec import OPTION, parse_physics, resolve_physics
    from wcbench.methods.weathercity import profile_physics
    from wcbench.reference_model.devices import device_problem
    from wcbench.reference_model.training.config import make_config
    from wcbench.scenes.sets import resolve_scenes

    options = training_options(args)  # every value checked against weathercity's declared options
    device = str(options.get("device", "cpu"))
    problem = device_problem(device)  # before any scene is read
    if problem is not None:
        raise InputError(f"--device {device}: {problem}")
    config = make_config(options.get("profile", "default"), ablation=options.get("ablation", ""),
                         holdout=options.get("holdout", ()), **(options.get("settings") or {}))
    jitter = float(options.get("jitter", 0.0))
    supervision = str(options.get("supervision", "physical-editor"))
    check_supervision(supervision, jitter)  # a jitter the supervision would ignore
    # as weathercity reads it: a profile's own physics presets unless the option names others
    physics = parse_physics(profile_physics(options.get("profile", "default"), options.get(OPTION)), who="train")
    if args.out is not None:
        check_writable_folder(args.out)
    refs = resolve_scenes(args.scenes, data_root=args.data_root)
    if args.checkpoint is not None and len(refs) > 1:
        raise InputError(f"--checkpoint names one folder, but {args.scenes} has {len(refs)} scenes")
    # the content loss's VGG16, fetched before the first scene trains (skipped with the reason if it stays missing)
    models = fetch_missing(["vgg16"] if config.content_weight != 0 else [], offline=is_offline(args.offline))
    with kernels_compiled_aside():  # a fresh install's kernels compile beside the first scene's set-up
        for ref in refs:
            scene = ref.load()
            bad = [h for h in config.holdout if not 0 <= h < len(scene)]
            if bad:
                raise InputError(f"--holdout {bad}: {scene.id} has frames 0..{len(scene) - 1}")
            # the physics `run --method weathercity` trains with (same physics option; seed 0 and no particle
            # draw, as WeatherCityMethod.training_physics), so that it finds this model
            _, _, facts = train_scene(scene, config, supervision=supervision, jitter=jitter,
                                      physics=resolve_physics(scene, physics, seed=0, draws=False),
                                      folder=args.checkpoint, device=device,
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
