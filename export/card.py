"""Write or check model folders' cards (README.md) from their manifests.

    python -m export.card                                        # check every shipped folder's card
    python -m export.card --model service/models/NAME --write    # (re)write one card
    python -m export.card --write                                # (re)write every shipped card

``write_manifest`` already rewrites the card whenever a manifest is written (``export.to_onnx``,
``export.quantize``, ``export.measure --write``, ``export.baseline``); this command is for a manifest
edited by hand and for a check in CI: without ``--write`` it exits 1 naming each card that differs from
what its manifest gives.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from service.features.card import CARD_NAME, model_card, write_card
from service.features.manifest import MANIFEST_NAME, MODELS_DIR, ModelError, load_manifest


def shipped_folders() -> list[Path]:
    """Every model folder of the package (service/models/*/ with a manifest)."""
    return sorted(path.parent for path in MODELS_DIR.glob(f"*/{MANIFEST_NAME}"))


def stale_cards(folders: list[Path]) -> list[Path]:
    """The folders whose README.md is missing or differs from the card of their manifest."""
    stale = []
    for folder in folders:
        card = folder / CARD_NAME
        expected = model_card(load_manifest(folder))
        if not card.is_file() or card.read_text(encoding="utf-8") != expected:
            stale.append(folder)
    return stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m export.card", description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", action="append", type=Path, metavar="DIR",
                        help="model folder (repeatable; default: every folder in service/models)")
    parser.add_argument("--write", action="store_true", help="write DIR/README.md from DIR/manifest.json")
    args = parser.parse_args(argv)
    folders = args.model or shipped_folders()
    try:
        if args.write:
            for folder in folders:
                print(f"wrote {write_card(folder, load_manifest(folder))}", file=sys.stderr)
            return 0
        stale = stale_cards(folders)
    except (OSError, ModelError) as error:
        print(f"export.card: error: {error}", file=sys.stderr)
        return 1
    for folder in stale:
        print(f"export.card: {folder / CARD_NAME} does not match {folder / MANIFEST_NAME}; run "
              f"`python -m export.card --model {folder} --write`", file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
