"""Side-by-side benchmark of `ecology configure`'s planner against clingo and HiGHS.

Run through `scripts/bench-config`, which builds the planner's `sharing`
example and installs clingo into a virtual environment. For each point and
seed it writes one instance of `ecology_config::synthetic::sharing` to files,
then solves those same files with our planner (the `sharing solve` example),
with clingo (an ASP encoding read from the same files, #minimize) and with
HiGHS (a 0-1 program from the same files), and prints the times, the costs and
the ratio to the fastest peer that proved optimality. Both times exclude reading and
parsing the files; ours includes compiling, grounding and search, clingo's
includes its grounding and solving, HiGHS's includes building the model. Both report the median of up to five runs
while they take under half a second in all. Costs must agree where both prove
optimality; the script fails otherwise.
"""

import os
import re
import subprocess
import sys
import tempfile
import time

import clingo
import highspy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE = os.environ.get(
    "SHARING_EXAMPLE",
    os.path.join(ROOT, "target", "release", "examples", "sharing"),
)
TIMEOUT_S = float(os.environ.get("BENCH_TIMEOUT_S", "60"))

# (label, P, L, K, cpp, R, f)
POINTS = [
    ("P=4", 4, 3, 2, 1, 2, 0.0),
    ("P=8", 8, 3, 2, 1, 2, 0.0),
    ("P=16", 16, 3, 2, 1, 2, 0.0),
    ("P=32", 32, 3, 2, 1, 2, 0.0),
    ("P=64", 64, 3, 2, 1, 2, 0.0),
    ("P=128", 128, 3, 2, 1, 2, 0.0),
    ("P=8 L=4", 8, 4, 2, 1, 2, 0.0),
    ("P=8 L=5", 8, 5, 2, 1, 2, 0.0),
    ("P=8 K=3 R=3", 8, 3, 3, 1, 3, 0.0),
    ("P=8 cpp=2", 8, 3, 2, 2, 2, 0.0),
    ("P=8 cpp=4", 8, 3, 2, 4, 2, 0.0),
    ("P=8 f=0.2", 8, 3, 2, 1, 2, 0.2),
    ("P=16 L=4", 16, 4, 2, 1, 2, 0.0),
    ("P=16 L=5", 16, 5, 2, 1, 2, 0.0),
    ("P=16 K=3 R=3", 16, 3, 3, 1, 3, 0.0),
    ("P=16 cpp=2", 16, 3, 2, 2, 2, 0.0),
    ("P=16 cpp=4", 16, 3, 2, 4, 2, 0.0),
    ("P=16 f=0.2", 16, 3, 2, 1, 2, 0.2),
    ("P=32 L=4", 32, 4, 2, 1, 2, 0.0),
    ("P=32 K=3 R=3", 32, 3, 3, 1, 3, 0.0),
    ("P=32 cpp=4", 32, 3, 2, 4, 2, 0.0),
    ("P=32 f=0.2", 32, 3, 2, 1, 2, 0.2),
]
SEEDS = [int(s) for s in os.environ.get("BENCH_SEEDS", "1 2 3").split()]
# A regular expression selecting points by label, e.g. "^P=32$".
ONLY = re.compile(os.environ.get("BENCH_POINTS", ""))


def read_instance(directory):
    """Components, channel costs and the user, from the written files."""
    with open(os.path.join(directory, "state.facts")) as f:
        facts = f.read()
    with open(os.path.join(directory, "domain.eco")) as f:
        domain = f.read()
    with open(os.path.join(directory, "exclusions")) as f:
        excluded = {tuple(line.strip().split(":")) for line in f if line.strip()}
    signature = {}
    for name, inputs, output in re.findall(
        r"\(:functionality (f\d+) .*?:input \(((?:\([^()]*\))*)\) :output \(\(([^()]*)\)\)",
        domain,
        re.S,
    ):
        signature[name[1:]] = (output.strip(), re.findall(r"\(([^()]*)\)", inputs))
    comps = {}
    for peis, comp, sig in re.findall(r"\(sig (\S+) (\S+) s(\d+)\)", facts):
        if (peis, comp) in excluded:
            continue
        out, ins = signature[sig]
        comps[(peis, comp)] = {"provides": out, "needs": ins}
    cost = {(p, c): int(n) for p, c, n in re.findall(r"\(cost (\S+) (\S+) (\d+) on\)", facts)}
    for key in comps:
        comps[key]["cost"] = cost[key]
    chan = {(a, b): int(n) for a, b, n in re.findall(r"\(channel-cost (\S+) (\S+) (\d+)\)", facts)}
    (user,) = re.findall(r"\(user (\S+) (\S+)\)", facts)
    return comps, chan, user


def asp_program(comps, chan, user):
    peis_ids = {}
    pid = lambda p: peis_ids.setdefault(p, len(peis_ids))
    type_ids = {}
    tid = lambda t: type_ids.setdefault(t, len(type_ids))
    lines = []
    ids = {}
    for i, (key, c) in enumerate(sorted(comps.items())):
        ids[key] = i + 1
        lines.append(f"comp({i + 1},{pid(key[0])},{c['cost']},{tid(c['provides'])}).")
        for n in c["needs"]:
            lines.append(f"need({i + 1},{tid(n)}).")
    lines.append(f"comp(0,{pid(user[0])},0,-1). need(0,{tid('goal')}). use(0).")
    for (a, b), n in chan.items():
        if a in peis_ids and b in peis_ids:
            lines.append(f"chan({pid(a)},{pid(b)},{n}).")
    lines.append(
        """
1 { feed(C,T,D) : comp(D,_,_,T) } 1 :- use(C), need(C,T).
use(D) :- feed(_,_,D).
wire(C,T,N) :- feed(C,T,D), comp(C,P,_,_), comp(D,Q,_,_), P != Q, chan(Q,P,N).
#minimize { N,c,C : use(C), comp(C,_,N,_) ; N,w,C,T : wire(C,T,N) }.
"""
    )
    return "\n".join(lines)


def clingo_solve(program):
    """(seconds, cost, proven): the median of up to five runs while they take
    under half a second in all, as for our planner."""
    runs = []
    began = time.perf_counter()
    while len(runs) < 5 and (not runs or time.perf_counter() - began < 0.5):
        runs.append(clingo_once(program))
    runs.sort(key=lambda r: r[0])
    return runs[len(runs) // 2]


def clingo_once(program):
    """(seconds, cost, proven) for the program, single-threaded."""
    start = time.perf_counter()
    ctl = clingo.Control(["--opt-mode=opt", "--parallel-mode=1"])
    ctl.add("base", [], program)
    ctl.ground([("base", [])])
    best = [None]

    def on_model(model):
        best[0] = model.cost[0] if model.cost else 0

    with ctl.solve(on_model=on_model, async_=True) as handle:
        finished = handle.wait(max(0.0, TIMEOUT_S - (time.perf_counter() - start)))
        if not finished:
            handle.cancel()
        result = handle.get()
    elapsed = time.perf_counter() - start
    proven = finished and result.exhausted
    return elapsed, best[0], proven


def highs_once(comps, chan, user):
    """(seconds, cost, proven) for the instance as a MILP, single-threaded.

    x_c: component c is used; y_ctd: consumer c's need t is fed by d.
    Each need of a used consumer is fed exactly once, only by used
    providers; the user is used. Types are levelled, so no cycles arise.
    """
    start = time.perf_counter()
    keys = sorted(comps)
    index = {k: i for i, k in enumerate(keys)}
    by_type = {}
    for k in keys:
        by_type.setdefault(comps[k]["provides"], []).append(index[k])
    consumers = [(index[k], comps[k]["needs"], k[0]) for k in keys] + [(len(keys), ["goal"], user[0])]
    n_x = len(keys) + 1
    cost = [comps[k]["cost"] for k in keys] + [0]
    lower = [0.0] * n_x
    lower[len(keys)] = 1.0
    y_cost, y_cons, y_prov = [], [], []
    rows = []  # (indices, values, lo, hi)
    for c, needs, peis in consumers:
        for t in needs:
            feeders = by_type.get(t, [])
            ys = []
            for d in feeders:
                j = n_x + len(y_cost)
                q = keys[d][0]
                y_cost.append(0 if q == peis else chan[(q, peis)])
                ys.append(j)
                rows.append(([j, d], [1.0, -1.0], -highspy.kHighsInf, 0.0))
            rows.append((ys + [c], [1.0] * len(ys) + [-1.0], 0.0, 0.0))
    n = n_x + len(y_cost)
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("threads", 1)
    h.setOptionValue("time_limit", TIMEOUT_S)
    obj = np.array(cost + y_cost, dtype=float)
    h.addVars(n, np.array(lower + [0.0] * len(y_cost)), np.ones(n))
    h.changeColsCost(n, np.arange(n, dtype=np.int32), obj)
    h.changeColsIntegrality(n, np.arange(n, dtype=np.int32), np.array([highspy.HighsVarType.kInteger] * n))
    lo = np.array([r[2] for r in rows])
    hi = np.array([r[3] for r in rows])
    starts = np.cumsum([0] + [len(r[0]) for r in rows[:-1]]).astype(np.int32)
    idx = np.array([i for r in rows for i in r[0]], dtype=np.int32)
    val = np.array([v for r in rows for v in r[1]], dtype=float)
    h.addRows(len(rows), lo, hi, len(idx), starts, idx, val)
    h.run()
    elapsed = time.perf_counter() - start
    status = h.getModelStatus()
    # An infeasible model is a proven "no configuration".
    proven = status in (highspy.HighsModelStatus.kOptimal, highspy.HighsModelStatus.kInfeasible)
    info = h.getInfo()
    value = round(info.objective_function_value) if info.primal_solution_status == 2 else None
    return elapsed, value, proven


def highs_solve(comps, chan, user):
    runs = []
    began = time.perf_counter()
    while len(runs) < 5 and (not runs or time.perf_counter() - began < 0.5):
        runs.append(highs_once(comps, chan, user))
    runs.sort(key=lambda r: r[0])
    return runs[len(runs) // 2]


def ours(directory):
    out = subprocess.run(
        [EXAMPLE, "solve", directory, str(int(TIMEOUT_S * 1000))],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    fields = dict(kv.split("=") for kv in out.split())
    cost = None if fields["cost"] == "none" else int(fields["cost"])
    first = None if fields["first_micros"] == "none" else int(fields["first_micros"]) / 1e6
    return int(fields["micros"]) / 1e6, cost, fields["status"] == "Proven", first


def human(seconds):
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    if seconds < 1:
        return f"{seconds * 1e3:.1f} ms"
    return f"{seconds:.2f} s"


def main():
    print("| point | seed | components | ours | first found | clingo | HiGHS | cost: ours / clingo / HiGHS | fastest proven peer ÷ ours |")
    print("|---|---|---|---|---|---|---|---|---|")
    failures = 0
    worst = None
    with tempfile.TemporaryDirectory() as tmp:
        for label, p, l, k, cpp, r, f in POINTS:
            if not ONLY.search(label):
                continue
            for seed in SEEDS:
                d = os.path.join(tmp, f"{label}-{seed}".replace(" ", "_"))
                subprocess.run(
                    [EXAMPLE, "export", d, str(p), str(l), str(k), str(cpp), str(r), str(f), str(seed)],
                    check=True,
                )
                t_ours, c_ours, p_ours, first = ours(d)
                comps, chan, user = read_instance(d)
                peers = [
                    clingo_solve(asp_program(comps, chan, user)),
                    highs_solve(comps, chan, user),
                ]
                mark = lambda c, proven: "none" if c is None else f"{c}{'' if proven else '?'}"
                proven_costs = {c for _, c, pr in peers if pr}
                if p_ours:
                    proven_costs.add(c_ours)
                agree = len(proven_costs) <= 1
                if not agree:
                    failures += 1
                proven_times = [t for t, _, pr in peers if pr]
                if proven_times and p_ours:
                    ratio = min(proven_times) / t_ours
                    worst = ratio if worst is None else min(worst, ratio)
                    ratio_text = f"{ratio:.0f}×"
                else:
                    fastest = min(t for t, _, _ in peers)
                    ratio_text = f"> {fastest / t_ours:.0f}× (no peer proved)"
                timing = lambda t, proven: f"{human(t)}{'' if proven else ' (not proven)'}"
                print(
                    f"| {label} | {seed} | {len(comps) + 1} | {timing(t_ours, p_ours)} "
                    f"| {'-' if first is None else human(first)} "
                    f"| {timing(peers[0][0], peers[0][2])} | {timing(peers[1][0], peers[1][2])} "
                    f"| {mark(c_ours, p_ours)} / {mark(peers[0][1], peers[0][2])} / {mark(peers[1][1], peers[1][2])}"
                    f"{'' if agree else ' DISAGREE'} | {ratio_text} |",
                    flush=True,
                )
    print()
    print(f"`?`: not proven optimal within the budget of {TIMEOUT_S:.0f} s per solver and instance. "
          f"Smallest ratio where a peer proved: {'-' if worst is None else f'{worst:.1f}×'}")
    if failures:
        print(f"{failures} disagreements between proven optima", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
