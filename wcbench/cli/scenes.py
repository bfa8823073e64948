"""List the built-in scene sets, or show what one scene set (or scene folder) holds.

Examples::

    wcbench scenes list
    wcbench scenes show pandaset_002 --data-root ../shared/data
    wcbench scenes show path/to/processed/scene
"""

from __future__ import annotations

import argparse
from typing import Any

from wcbench.cli.common import add_data_root_argument

HELP = "list scene sets or show one"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``list`` and ``show NAME``."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="list the built-in scene sets")
    show = sub.add_parser("show", help="load a scene set or folder and describe its scenes")
    show.add_argument("name", help="scene set name or scene folder path")
    add_data_root_argument(show)


def run(args: argparse.Namespace) -> int:
    """Print the listing."""
    from wcbench.core.classes import CLASSES
    from wcbench.scenes.sets import list_scene_sets, resolve_scenes

    if args.action == "list":
        for name, desc in list_scene_sets():
            print(f"{name:14s} {desc}")
        return 0
    for ref in resolve_scenes(args.name, data_root=args.data_root):
        scene = ref.load()
        w, h = scene.image_size
        with_lidar = sum(f.lidar_path is not None for f in scene.frames)
        classes: dict[str, int] = {}
        for t in scene.tracks:
            classes[t.class_name] = classes.get(t.class_name, 0) + 1
        order = {c: n for n, c in enumerate(CLASSES)}
        print(f"{scene.id}: {len(scene)} frames {w}x{h}, {scene.duration:.1f} s, format {scene.source_format}")
        print(f"  folder       {scene.root}")
        print(f"  lidar        {with_lidar}/{len(scene)} frames")
        offset = [round(float(v), 3) for v in scene.world_offset]
        print(f"  up vector    {scene.up.tolist()}  (world re-based by {offset})")
        counts = sorted(classes.items(), key=lambda kv: (order.get(kv[0], len(order)), kv[0]))
        print(f"  tracks       {len(scene.tracks)} " + ", ".join(f"{k}: {v}" for k, v in counts))
        print(f"  sky masks    {sum(f.sky_mask_path is not None for f in scene.frames)} frames")
        if scene.edit_truths:  # the --edit forms whose runs are scored against an editing truth
            print("  edit truth   " + "; ".join(_edit_text(t.edit) for t in scene.edit_truths))
        for key, value in sorted(scene.facts.items()):
            print(f"  {key + ' ':12s} {value}")
        if scene.tracks:
            # drivestudio's compact ids, the ones --edit "... ids=0,3" names; the dataset's own
            # class and id follow for reference
            print("  id  class       frames  source class / id")
            for t in sorted(scene.tracks, key=lambda t: (len(t.id), t.id)):
                print(f"  {t.id:>3s} {t.class_name:11s} {int(t.frames.min()):3d}-{int(t.frames.max()):<3d}  "
                      f"{t.source_class or '-'} / {t.source_id or '-'}")
    return 0


def _edit_text(edit: dict[str, Any]) -> str:
    """An edit's ``--edit`` text form from its JSON form (``op``, ``ids``, ``by``)."""
    by = "" if edit.get("by") is None else " by=" + ",".join(f"{float(v):g}" for v in edit["by"])
    return f"{edit['op']} ids={','.join(edit.get('ids', []))}{by}"
