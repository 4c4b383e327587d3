"""`drapelab demo`: placeholder until the simulator facade lands (prints a notice)."""


def register(subparsers):
    p = subparsers.add_parser("demo", help="demo (not implemented yet)")
    p.set_defaults(func=run)


def run(args):
    print("drapelab demo: not implemented yet")
    return 1
