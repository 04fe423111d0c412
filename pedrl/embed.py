"""``python -m pedrl.embed CHECKPOINT ROOM.wkt [--output PATH]``: re-export a checkpoint that names its room's file.

Checkpoints hold their room: a custom room's WKT text is stored in them. Checkpoints written before that name the
room's WKT file (``scenario.geometry``) instead, and pedrl opens no file a checkpoint names, so ``pedrl-eval``,
``pedrl-validate`` and ``resume=`` refuse them with the command line that re-exports them: this one. It stores the
WKT text of ROOM.wkt in the checkpoint (:func:`pedrl.configs.embed_geometry`); a bad value ends in one line
and exit code 2.
"""

from __future__ import annotations

from pathlib import Path

from pedrl.common.commands import OneLineParser, describe_os_error, fail
from pedrl.configs import embed_geometry
from pedrl.io import CheckpointError
from pedrl.io.files import check_outputs

PROGRAM = "python -m pedrl.embed"
DESCRIPTION = (
    "Store the WKT text of a custom room in a checkpoint that names the room's WKT file (a checkpoint written before"
    " checkpoints held their room), so that pedrl-eval, pedrl-validate and resume= accept it."
)


def main(argv: list[str] | None = None) -> None:
    """Parse the command line and re-export the checkpoint."""
    parser = OneLineParser(prog=PROGRAM, description=DESCRIPTION)
    parser.add_argument("checkpoint", help="a .safetensors checkpoint whose scenario.geometry names a WKT file")
    parser.add_argument("wkt", help="the WKT file it was trained on")
    parser.add_argument("--output", default=None, help="where to write the re-exported checkpoint (default: in place)")
    args = parser.parse_args(argv)
    try:  # the file written is checked before the checkpoint is read
        if args.output is not None:
            check_outputs(files=[args.output])
        elif Path(args.checkpoint).is_file():
            check_outputs(files=[args.checkpoint])
        written = embed_geometry(args.checkpoint, args.wkt, output=args.output)
    except (CheckpointError, ValueError) as err:
        fail(PROGRAM, str(err))
    except OSError as err:
        fail(PROGRAM, describe_os_error(err))
    print(f"{PROGRAM}: {str(written)!r} now holds its room")


if __name__ == "__main__":
    main()
