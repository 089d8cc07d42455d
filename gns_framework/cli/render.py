"""``gns render``: turn a rollout file into VTK frames and a side-by-side GIF."""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

from .arguments import add_overwrite, positive_int

ROLLOUT_HELP = (
    "what gns rollout wrote: a rollout file (.npz), or the folder of a rollout over several processes (.rollout)"
)


def _gif_path(value: str) -> Path:
    path = Path(value)
    if path.suffix.lower() != ".gif":
        raise argparse.ArgumentTypeError(f"{value}: the animation is written as .gif")
    return path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("rollout", type=Path, metavar="ROLLOUT", help=ROLLOUT_HELP)
    parser.add_argument(
        "--vtk",
        type=Path,
        metavar="DIR",
        help="folder for predicted/ and ground_truth/ frames and their .pvd collections",
    )
    parser.add_argument("--gif", type=_gif_path, metavar="FILE", help="animation, prediction beside ground truth")
    parser.add_argument(
        "--every", type=positive_int, default=1, metavar="K", help="animate every K-th frame (default 1)"
    )
    add_overwrite(parser, "replace an existing --gif file, or write into a --vtk folder holding something else")
    parser.add_argument("--fps", type=positive_int, default=20, help="frames per second of the GIF (default 20)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from ..io.rollout_file import load_rollout
    from ..plugins import load_registry

    if args.vtk is None and args.gif is None:
        print("gns render: error: nothing to do: give --vtk DIR and/or --gif FILE", file=sys.stderr)
        return 2
    from ..outputs import check_file, check_folder, claim_folder

    if args.vtk is not None:
        check_folder(args.vtk, "render", args.overwrite)
    if args.gif is not None:
        check_file(args.gif, "render", args.overwrite, "--gif")
    rollout = load_rollout(args.rollout)
    materials = load_registry().material_names(rollout.particle_type)
    if args.vtk is not None:
        from ..io.vtk import write_rollout_vtk

        claim_folder(args.vtk, "render", args.overwrite)
        with _progress("VTK frames", args.no_progress) as progress:
            written = write_rollout_vtk(rollout, args.vtk, progress=progress, material_names=materials)
        for name, pvd in written.items():
            print(f"{name}: {pvd}")
    if args.gif is not None:
        from ..viz.animation import animate_rollout

        with _progress("GIF frames", args.no_progress) as progress:
            gif = animate_rollout(
                rollout, args.gif, every=args.every, fps=args.fps, material_names=materials, progress=progress
            )
        print(f"animation: {gif}")
    return 0


@contextlib.contextmanager
def _progress(what: str, quiet: bool) -> Iterator[Callable[[int, int], None] | None]:
    """A ``progress(done, total)`` callback drawing a bar on stderr (drawing a GIF takes ~0.3 s a frame), or None."""
    if quiet:
        yield None
        return
    from tqdm import tqdm

    with tqdm(desc=f"render {what}", unit="frame", file=sys.stderr) as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        yield progress
