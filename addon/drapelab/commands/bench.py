"""`drapelab bench`: placeholder until the simulator facade lands (prints a notice)."""


def register(subparsers):
    p = subparsers.add_parser("bench", help="bench (not implemented yet)")
    p.set_defaults(func=run)


def run(args):
    print("drapelab bench: not implemented yet")
    return 1
