"""CLI: `ocplace export`: a trained Ours run as a policy folder that loads anywhere."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        help="write a trained Ours run as a policy folder (config.json, model.safetensors, README.md)",
        description="Writes the run's backbone, adapters and settings into one folder that "
        "`PlacementPolicy.from_pretrained(DIR)` and `ocplace place --policy DIR` load with no cache "
        "(docs/policy.md, 'Policy folders').",
    )
    parser.add_argument("--run", type=Path, required=True, help="an Ours training run (e.g. out/demo/runs/ours/...)")
    parser.add_argument("--out", type=Path, required=True, help="the policy folder to write")
    parser.add_argument(
        "--backbone",
        help="backbone spec (default: the saved offline backbone the run was trained with, found by its fingerprint)",
    )
    parser.add_argument("--parser", default="offline", help="the parser the folder records: offline or offline-snap")
    parser.set_defaults(func=run_export)


def run_export(args: argparse.Namespace) -> int:
    from ocplace.methods.export import export_run
    from ocplace.paths import check_writable

    check_writable(args.out, as_folder=True)  # a file there is an OutputError, before the backbone loads
    folder = export_run(args.run, args.out, backbone=args.backbone, parser=args.parser)
    print(f"wrote the policy folder {folder}: load it with PlacementPolicy.from_pretrained({str(folder)!r})")
    return 0
