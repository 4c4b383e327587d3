"""`drapelab effects [--json OUT.json]`: the registry of optional physical effects.

Prints every registered effect: its name, a one-line explanation, the signature it predicts on a drape, and
its parameters (name, unit, off value, allowed range, prior scale for fitting, a moderate strength). The first
parameter of each effect is its primary one (`fit --effects NAME=VALUE` sets it). --json writes the same as
a list of objects (the output of drapelab.sim.effects()).
"""


def register(subparsers):
    p = subparsers.add_parser("effects", help="list the optional physical effects (name, parameters, units)",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--json", metavar="OUT.json", default=None, help="also write the registry here")
    p.set_defaults(func=run)


def _range(q):
    lo = "-inf" if q["lower"] == float("-inf") else f"{q['lower']:g}"
    hi = "inf" if q["upper"] == float("inf") else f"{q['upper']:g}"
    return f"[{lo}, {hi}]"


def run(args):
    from .. import measure, sim

    registry = sim.effects()
    if args.json:
        measure.check_output_path(args.json, "JSON")
    for e in registry:
        print(f"{e['name']}: {e['explanation']}")
        print(f"  signature: {e['signature']}")
        for i, q in enumerate(e["parameters"]):
            primary = " (primary)" if i == 0 else ""
            print(f"  {q['name']}{primary}: {q['description']}; unit {q['unit']}, off {q['off']:g}, "
                  f"range {_range(q)}, prior scale {q['prior_scale']:g}, moderate {q['moderate']:g}")
    if args.json:
        finite = [{**e, "parameters": [{k: (None if isinstance(v, float) and abs(v) == float("inf") else v)
                                        for k, v in q.items()} for q in e["parameters"]]} for e in registry]
        measure.write_json(args.json, {"effects": finite})
    return 0
