"""Ship a detector checkpoint inside the package: its weights in fp16 (the design run loads them
into a float32 detector), its training and tuning record kept, and an entry in the manifest
python/optix_e2e/tasks/bundled/detectors.json (file, sha256, the source's sha256, the commands
that made it, measured mAP):

    python scripts/bundle_detector.py SRC NAME --made-by "COMMANDS" [--file FILE] [--measured JSON]...

--measured adds a JSON file of measurements (e.g. `optix detect eval`'s output, as "clean",
or `optix detect tune`'s tune.json, as "tune") to the entry: --measured clean=PATH.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import torch

from optix_e2e.io import save_atomic, write_json_atomic
from optix_e2e.tasks.detector_train import load_detector
from optix_e2e.tasks.shipped_detectors import BUNDLED, MANIFEST

KEEP = ("format", "config", "step", "steps", "seed", "dim", "noise", "wall_s", "data", "tuned", "isp_unit")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src", type=Path)
    ap.add_argument("name")
    ap.add_argument("--made-by", required=True)
    ap.add_argument("--file", default=None, help="the bundled file's name (default: NAME with _ and .pt)")
    ap.add_argument("--measured", action="append", default=[], metavar="KEY=JSON")
    a = ap.parse_args()
    _, ck = load_detector(a.src)  # the checkpoint as plain data, or one error naming it
    small = {k: ck[k] for k in KEEP if k in ck}
    small["state_dict"] = {k: v.to(torch.float16) if v.is_floating_point() else v for k, v in ck["state_dict"].items()}
    file = a.file or a.name.replace("-", "_") + ".pt"
    save_atomic(small, BUNDLED / file)
    load_detector(BUNDLED / file)  # it loads back
    manifest = json.loads(MANIFEST.read_text()) if MANIFEST.is_file() else {}
    entry = {
        "file": file,
        "sha256": hashlib.sha256((BUNDLED / file).read_bytes()).hexdigest(),
        "source_sha256": hashlib.sha256(a.src.read_bytes()).hexdigest(),
        "made_by": a.made_by,
        "weights": "fp16",
        "step": ck.get("step"),
        "hardware_isp_tuned": "isp_unit" in ck,
    }
    for item in a.measured:
        key, _, path = item.partition("=")
        entry[key] = json.loads(Path(path).read_text())
    manifest[a.name] = entry
    write_json_atomic(MANIFEST, manifest)
    print(json.dumps({a.name: {k: v for k, v in entry.items() if k not in ("clean", "tune")}}, indent=2))


if __name__ == "__main__":
    main()
