"""``calnav view PATH``: open Rerun recordings in the Rerun viewer (the ``[viz]`` extra).

PATH is an ``.rrd`` file, a ``map.npz`` of ``calnav map`` (logged to ``<stem>.rrd`` beside it
first, unless that exists and is newer: the map by class and by confidence), or a results
directory (its ``map.rrd`` / ``rerun/*.rrd``, else its ``map.npz``). With a display the viewer is
started (``python -m rerun FILE...``); without one (no ``$DISPLAY`` / ``$WAYLAND_DISPLAY``, or
``--print``) the command is printed instead, with the web viewer's form for a remote machine.
"""
from __future__ import annotations

import os
import shlex
import subprocess
import sys
import zipfile
from pathlib import Path

from calnav.common.rerun_io import check_recording
from dataclasses import dataclass
from calnav.eval.arguments import REQUIRED, Command, arg

MAX_LISTED = 50   # recordings of one results directory handed to one viewer


def recordings(path: Path) -> list[Path]:
    """The ``.rrd`` files ``path`` stands for (making one from a ``map.npz``); ValueError when
    there is nothing to view."""
    if not path.exists():
        raise ValueError(f"{path} does not exist; give an .rrd file, a map.npz or a results directory")
    if path.is_dir():
        found = sorted(path.glob("*.rrd")) + sorted((path / "rerun").glob("*.rrd"))
        if found:
            for rrd in found[:MAX_LISTED]:
                check_recording(rrd)
            return found[:MAX_LISTED]
        if (path / "map.npz").is_file():
            return [npz_recording(path / "map.npz")]
        raise ValueError(f"{path} holds no recording (*.rrd, rerun/*.rrd) and no map.npz; make one with "
                         "calnav objectnav --rerun N or calnav map ... --rerun")
    if path.suffix == ".rrd":
        check_recording(path)
        return [path]
    if path.suffix == ".npz":
        return [npz_recording(path)]
    raise ValueError(f"{path}: cannot view a {path.suffix or 'suffix-less'} file; give an .rrd file, a map.npz or a "
                     "results directory")


def npz_recording(npz: Path) -> Path:
    """``<stem>.rrd`` beside a ``calnav map`` ``map.npz``: the map by class and by confidence."""
    from calnav.agent.visualize import class_palette
    from calnav.common import rerun_io
    from calnav.common.npz import load_versioned_npz
    from calnav.eval.sequence.map_cmd import MAP_FORMAT_VERSION

    out = npz.with_suffix(".rrd")
    if out.exists() and out.stat().st_mtime >= npz.stat().st_mtime:
        check_recording(out)
        return out
    # an .npz is a zip archive: anything else would reach numpy's pickle reader, whose error
    # advises allow_pickle (never right for a map file)
    if not zipfile.is_zipfile(npz):
        raise ValueError(f"{npz} is not a calnav map: not an .npz (zip) archive; make one with calnav map ... "
                         "--output DIR (DIR/map.npz)")
    arrays, meta = load_versioned_npz(npz, MAP_FORMAT_VERSION, "calnav map file", error=ValueError)
    names = list(meta.get("class_names", []))
    if not names or "centres" not in arrays or "probs" not in arrays or arrays["probs"].shape[1:] != (len(names),):
        raise ValueError(f"{npz} is not a calnav map (centres, probs (N, K) and K class names)")
    palette = class_palette(len(names))
    rec = rerun_io.new_recording("calnav map", out, names, palette)
    rerun_io.log_voxels(rec, "world/map", arrays["centres"], arrays["probs"], float(meta.get("voxel_size_m", 0.05)),
                        palette, static=True)
    rec.flush()
    rec.disconnect()
    return out


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform == "darwin"


def main_view(args, configs=()) -> None:
    from calnav.common.rerun_io import require_rerun

    require_rerun("calnav view")
    files = recordings(Path(args.path))
    cmd = [sys.executable, "-m", "rerun", *map(str, files)]
    if args.print or not has_display():
        why = "" if args.print else " (no display here: run it where there is one, or serve the web viewer)"
        print(f"{len(files)} recording(s){why}:")
        print("  " + shlex.join(["rerun", *map(str, files)]))
        print("  " + shlex.join(["rerun", "--web-viewer", *map(str, files)]) + "   # then open the printed address")
        return
    subprocess.Popen(cmd, start_new_session=True)   # the viewer outlives this command
    print(f"opened {len(files)} recording(s) in the Rerun viewer")


@dataclass
class ViewArgs:
    """``calnav view``'s flags."""

    path: str = arg(REQUIRED, "an .rrd file, a calnav map map.npz, or a results directory", positional=True)
    print: bool = arg(False, "print the viewer command instead of starting it")


COMMAND = Command(ViewArgs, main_view, sections=(), overrides=None)   # reads recordings, no config
