"""`python -m plmarl_sitl.learning.nn.convert DIR...`: re-export policy directories exported
before the fused deployment form (`fused.py`) in that form, in place, without their training
checkpoints (the weights are read back from the frozen file: `fused.fused_policy_from_file`).

Its own module because it both loads and exports (`io.py`) and fuses (`fused.py`); `io.py`
imports `fused.py` to export, so the converter cannot live in `fused.py` without an import
circle (tests/test_layers.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

from plmarl_sitl.errors import PolicyFileError, run_reporting
from plmarl_sitl.learning.nn.fused import fused_policy_from_file, is_fused
from plmarl_sitl.learning.nn.io import export_policy, load_policy

HOW = "python -m plmarl_sitl.learning.nn.convert DIR (weights read back from the frozen file; outputs equal to float32 rounding)"


def fuse_directory(directory: str | Path) -> dict:
    """Re-export a shipped policy directory with its policy in the fused form, in place
    (same weights, read back from the frozen file; no training checkpoint needed).

    The card keeps every field; `export` records the re-export and the previous files'
    sha256. Returns the new card (unchanged if there is nothing to fuse).
    """
    d = Path(directory)
    lp = load_policy(d)
    try:
        policy = fused_policy_from_file(lp.policy)
    except ValueError as exc:
        raise PolicyFileError(str(d / "policy.pt"), f"cannot fuse: {exc}") from exc
    if policy is lp.policy:
        return lp.card  # already fused, or not a version-2 policy with the plan
    card = {k: v for k, v in lp.card.items() if k not in ("card_version", "io", "sha256")}
    card["export"] = {
        "fused": {"predictor.pt": is_fused(lp.tracker), "policy.pt": True},
        "fused_from_sha256": dict(lp.card["sha256"]),
        "how": HOW,
    }
    export_policy(d, lp.tracker, policy, card)
    return load_policy(d).card


def main(argv: list[str]) -> int:
    """Fuse each policy directory in place. A directory that is not a loadable policy is one
    line and exit 2 (`run_reporting`); directories before it stay converted, it and those
    after are untouched."""
    if not argv:
        print("usage: python -m plmarl_sitl.learning.nn.convert POLICY_DIR [POLICY_DIR ...]", file=sys.stderr)
        return 2

    def body() -> None:
        for arg in argv:
            c = fuse_directory(arg)
            print(arg, c.get("export", {}).get("fused"), c["sha256"])

    return run_reporting("convert", body)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
