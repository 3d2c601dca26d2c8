"""One module per ``rgse`` sub-command, each with ``run(args: argparse.Namespace) -> int``."""
