"""Command-line interface: `./drapelab <command> ...` (see README.md)."""
import argparse
import importlib
import sys

# One module per command under drapelab.commands, each with register(subparsers) -> sets func.
# Module names (install_addon registers the subcommand install-addon).
COMMANDS = ["demo", "bench", "measure", "compare", "fit", "evaluate", "effects", "synth", "diagnose", "package",
            "install_addon", "drape"]


def main(argv=None):
    parser = argparse.ArgumentParser(prog="drapelab", description="Digitise fabrics from Cusick drape images.")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(f"drapelab.commands.{name}").register(sub)
    args = parser.parse_args(argv)
    from ._native import InputError, SolverError
    try:
        return args.func(args) or 0
    except (InputError, SolverError, ValueError, OSError) as e:
        print(f"drapelab {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
