"""`defocus convert-checkpoint`: rewrite a trusted old checkpoint so that it opens safely.

Every other command opens checkpoints with `torch.load(..., weights_only=True)` and refuses a
file that holds Python objects besides tensors and plain data. This command is the one exception:
it unpickles the old file with code execution enabled, so it runs whatever the file says. Use it
only on files you wrote yourself or whose author you trust.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from defocus.options import add_overwrite_argument

WARNING = ("WARNING: this runs any code stored in SOURCE (it is unpickled with "
           "weights_only=False); only convert checkpoints that you wrote yourself or whose "
           "author you trust. The result holds only tensors and plain data and opens safely.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = f"{parser.description}. {WARNING}"
    parser.add_argument("source", type=Path,
                        help="old checkpoint file (.pt) that you trust; it is run when read")
    parser.add_argument("target", type=Path,
                        help="new checkpoint file (.pt) to write (tensors and plain data only)")
    parser.add_argument("--trust", action="store_true",
                        help="required: confirm that you trust SOURCE, since reading it may run "
                             "code in it")
    add_overwrite_argument(parser)


def run(args: argparse.Namespace) -> int:
    from defocus.app.outputs import OutputPlan
    from defocus.errors import CommandError
    from models.checkpoints import convert_checkpoint

    for refused, message in (
            (not args.trust, f"not converting {args.source}: reading it may run code stored in "
             "it; add --trust if you wrote it yourself or trust its author"),
            (args.target.resolve() == args.source.resolve(),
             "give a new file as TARGET, not SOURCE itself")):
        if refused:
            raise CommandError(message)
    # the output policy: SOURCE never written, an existing TARGET kept unless --overwrite
    OutputPlan({"SOURCE": args.source}, overwrite=args.overwrite,
               how="or choose another TARGET").add(args.target, "checkpoint")
    convert_checkpoint(args.source, args.target)
    print(f"wrote {args.target} (tensors and plain data only; opens with weights_only=True)")
    return 0
