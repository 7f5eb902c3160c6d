"""Clip files as they lie on disk, without reading them: where an AMC file's skeleton is.
Nothing here imports numpy (the command line finds a clip's skeleton before it sends the files
unread to the pss service)."""

from __future__ import annotations

import re
from pathlib import Path

from shared.errors import ClipFormatError


def find_skeleton(amc_path) -> Path:
    """The ASF of an AMC file in the usual layouts: beside it or in a sibling ``asf/`` folder
    (also one level up, as in ``amc/<class>/x.amc`` + ``asf/``), named after the actor:
    ``HDM_bd_..._120.amc`` -> ``HDM_bd.asf``; CMU ``07_01.amc`` -> ``07.asf``."""
    amc_path = Path(amc_path)
    stem = amc_path.stem
    names = []
    m = re.match(r"^(HDM_[A-Za-z]+)_", stem)
    if m:
        names.append(m.group(1) + ".asf")
    m = re.match(r"^(\d+)_\d+$", stem)
    if m:
        names.append(m.group(1) + ".asf")
    names.append(stem + ".asf")
    parts = stem.split("_")
    for k in range(len(parts) - 1, 0, -1):
        names.append("_".join(parts[:k]) + ".asf")
    folders = [amc_path.parent, amc_path.parent / "asf", amc_path.parent.parent / "asf", amc_path.parent.parent.parent / "asf"]
    for folder in folders:
        for n in names:
            cand = folder / n
            if cand.is_file():
                return cand
    asfs = sorted(amc_path.parent.glob("*.asf"))
    if len(asfs) == 1:
        return asfs[0]
    raise ClipFormatError(amc_path, "no skeleton found: put the actor's .asf beside it or in a sibling asf/ folder, or pass --skeleton FILE")
