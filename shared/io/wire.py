"""Clip files that came over the bus (:func:`shared.clipfiles.wire_file`), read as files are."""

from __future__ import annotations

import re
from pathlib import Path

from shared.clipfiles import FILE_PATTERN
from shared.errors import BadInput, ClipFormatError


def read_wire_files(files: list[dict], reading: dict | None = None) -> list:
    """The clips of :func:`wire_file` entries, read as :func:`shared.io.load_clip` reads files
    (``reading``: units, up, translations), from a private temporary folder."""
    import tempfile

    from shared.io import load_clip  # the package's reader (this module is one of its parts)

    reading = {k: v for k, v in (reading or {}).items() if v is not None}
    clips = []
    with tempfile.TemporaryDirectory(prefix="mc-files-") as tmp:
        for i, f in enumerate(files):
            if not re.fullmatch(FILE_PATTERN, f["name"]):
                raise BadInput(f"files[{i}].name: {f['name']!r} is not a clip file name (NAME.amc, .bvh or .npz)",
                               field=f"files[{i}].name")
            folder = Path(tmp) / str(i)
            folder.mkdir()
            path = folder / f["name"]
            path.write_bytes(f["data"])
            skeleton = None
            if path.suffix.lower() == ".amc":
                if f.get("skeleton") is None:
                    raise BadInput(f"files[{i}]: an AMC file needs its skeleton (the ASF file's bytes)",
                                   field=f"files[{i}].skeleton")
                skeleton = folder / "skeleton.asf"  # read once per content (shared.io.load_skeleton)
                skeleton.write_bytes(f["skeleton"])
            try:
                clips.append(load_clip(path, skeleton=skeleton, **reading))
            except ClipFormatError as e:  # name the user's file, not the temporary copy
                raise BadInput(f"{f['name']}: {e.reason}", field=f"files[{i}]") from None
    return clips
