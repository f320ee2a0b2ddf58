"""Side-by-side benchmark of `ecology configure`'s planner against clingo, HiGHS
and a plain Python branch and bound.

Run through `scripts/bench-config`, which builds the planner's `sharing`
example and installs clingo and HiGHS into a virtual environment. For each
point and seed it writes one instance of `ecology_config::synthetic::sharing`
to files, then solves those same files with our planner (the `sharing solve`
example), with clingo (an ASP encoding read from the same files, #minimize),
with HiGHS (a 0-1 program from the same files) and with a best-first branch
and bound with duplicate detection in pure Python (standard library only,
what a user might write), and prints the times, the costs and the ratio to the
fastest peer that proved optimality. All times exclude reading and parsing
the files. Ours answers what the peers answer (the cheapest configuration, or
that there is none, without saying why) and includes reading the state,
grounding, search and assembling the configuration, with the domain compiled
beforehand by a
`Planner` (as the executive plans, and as the Python peer's reader turns the
domain's signatures into its table untimed); a second column also times
compiling the domain, as `ecology configure` does. Clingo's includes
its grounding and solving, HiGHS's includes building the model, the branch
and bound's its precomputation. All report the median of up to 1,000 runs
while they take under half a second in all. Costs must agree wherever two
prove optimality; the script fails otherwise. Where there is no
configuration, the "ours" cell also gives the time with the explanation that
`ecology configure` prints. The last line gives the smallest ratio apart for
instances with a configuration and without one.
"""

import heapq
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
# The Python branch and bound stops (not proven) beyond this many stored
# states, about 1.5 GB.
MAX_STATES = 5_000_000

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


def median_run(once, *args):
    """(seconds, cost, proven) of `once(*args)`: the median of up to 1,000
    runs while they take under half a second in all, as for our planner (a
    lone run, or the first few dozen, mostly measure cold caches, in an
    interpreter as in a binary)."""
    runs = []
    began = time.perf_counter()
    while len(runs) < 1000 and (not runs or time.perf_counter() - began < 0.5):
        runs.append(once(*args))
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


def bnb_once(comps, chan, user):
    """(seconds, cost, proven) for the instance by best-first branch and bound
    in plain Python (standard library only), as a user would write it.

    A partial configuration is the set of used components (a bit mask) and
    its open needs, grouped by (peis, type) with their multiplicity: feeding
    the needs of one type on one peis is one decision (the same provider
    serves them all optimally, since sharing is free and each feed pays the
    same channel). Needs are decided level by level (types by their distance
    from the goal), so all consumers of a type are known when it is decided.
    Expanding a state branches on the providers of its first open need: a
    used one costs the channels, a new one also its own cost and opens its
    needs. States wait in a heap ordered by cost so far plus a lower bound:
    each open need's cheapest channel, plus, for each type that must get a
    new provider (an open need and no used provider, or needed by every
    provider of such a type), its cheapest provider with the cheapest
    channels for that provider's own needs (one new component per type, so
    nothing is counted twice). Duplicates: a dict from the canonical state
    (used mask, open needs) to the cheapest cost so far that reached it; a
    state reached again at no lower cost is dropped. A greedy dive gives a
    first incumbent; states whose bound reaches the incumbent are pruned, and
    the incumbent is proven once the cheapest waiting bound reaches it.
    Cut off by the time limit, or beyond MAX_STATES stored states (memory),
    it reports the incumbent as not proven.
    """
    start = time.perf_counter()
    deadline = start + TIMEOUT_S
    keys = sorted(comps)
    # Types a component can only provide if all its needs can be fed.
    feasible = set()
    changed = True
    while changed:
        changed = False
        for k in keys:
            c = comps[k]
            if c["provides"] not in feasible and all(n in feasible for n in c["needs"]):
                feasible.add(c["provides"])
                changed = True
    usable = [k for k in keys if all(n in feasible for n in comps[k]["needs"])]
    if "goal" not in feasible:
        return time.perf_counter() - start, None, True
    # Depth of a type: its longest distance from the goal, so that a provider's
    # needs are always deeper than what it provides.
    needs_of = {}
    for k in usable:
        needs_of.setdefault(comps[k]["provides"], set()).update(comps[k]["needs"])
    depth = {"goal": 0}
    frontier = ["goal"]
    while frontier:
        t = frontier.pop()
        for u in needs_of.get(t, ()):
            if depth.get(u, -1) < depth[t] + 1:
                depth[u] = depth[t] + 1
                frontier.append(u)
    usable = [k for k in usable if comps[k]["provides"] in depth]  # the rest serve nothing
    types = sorted(depth, key=lambda t: (depth[t], t))
    tid = {t: i for i, t in enumerate(types)}
    peis = sorted({k[0] for k in usable} | {user[0]})
    pid = {p: i for i, p in enumerate(peis)}
    n_peis = len(peis)
    channel = [[0 if a == b else chan.get((a, b), 0) for b in peis] for a in peis]
    # Components: index, peis, own cost, type, needs (type ids).
    c_peis = [pid[k[0]] for k in usable]
    c_cost = [comps[k]["cost"] for k in usable]
    c_type = [tid[comps[k]["provides"]] for k in usable]
    c_needs = [sorted({tid[n] for n in comps[k]["needs"]}) for k in usable]
    providers = [[] for _ in types]
    for i, t in enumerate(c_type):
        providers[t].append(i)
    # An open need is coded as type * n_peis + peis: ascending order is level
    # order. min_chan[code]: the cheapest channel from any provider.
    min_chan = [
        min(channel[c_peis[d]][p] for d in providers[t]) if providers[t] else 0
        for t in range(len(types))
        for p in range(n_peis)
    ]
    # A new provider of a type costs at least this (its own cost and the
    # cheapest channels of its needs); forced[t]: types every provider of t needs.
    new_cost = [
        min(
            (c_cost[d] + sum(min_chan[u * n_peis + c_peis[d]] for u in c_needs[d]) for d in providers[t]),
            default=0,
        )
        for t in range(len(types))
    ]
    forced = []
    for t in range(len(types)):
        mask = None
        for d in providers[t]:
            m = 0
            for u in c_needs[d]:
                m |= 1 << u
            mask = m if mask is None else mask & m
        forced.append(mask or 0)

    def bound(open_needs, used_types):
        h = 0
        must = 0
        for code, m in open_needs:
            h += m * min_chan[code]
            t = code // n_peis
            if not used_types >> t & 1:
                must |= 1 << t
        # Close over the types every new provider of a required type needs.
        todo = must
        while todo:
            t = (todo & -todo).bit_length() - 1
            todo &= todo - 1
            h += new_cost[t]
            more = forced[t] & ~used_types & ~must
            must |= more
            todo |= more
        return h

    def children(g, used, used_types, open_needs):
        """(g, used, used_types, open_needs) for each choice of provider of
        the first open need."""
        code, m = open_needs[0]
        t, p = divmod(code, n_peis)
        rest = open_needs[1:]
        for d in providers[t]:
            q = c_peis[d]
            step = m * channel[q][p]
            if used >> d & 1:
                yield g + step, used, used_types, rest
                continue
            merged = dict(rest)
            for u in c_needs[d]:
                key = u * n_peis + q
                merged[key] = merged.get(key, 0) + 1
            yield g + step + c_cost[d], used | 1 << d, used_types | 1 << t, tuple(sorted(merged.items()))

    root = (0, 0, 0, ((tid["goal"] * n_peis + pid[user[0]], 1),))
    # Greedy dive: the child of least bound until nothing is open.
    g, used, used_types, open_needs = root
    while open_needs:
        g, used, used_types, open_needs = min(
            children(g, used, used_types, open_needs),
            key=lambda s: s[0] + bound(s[3], s[2]),
        )
    incumbent = g
    best_g = {(0, root[3]): 0}
    h = bound(root[3], 0)
    heap = [(h, h, 0, 0, 0, 0, root[3])]
    counter = 1
    expanded = 0
    while heap:
        f, _, _, g, used, used_types, open_needs = heapq.heappop(heap)
        if f >= incumbent:
            break
        if best_g.get((used, open_needs), g) < g:
            continue  # reached again more cheaply since
        expanded += 1
        if expanded % 64 == 0 and (time.perf_counter() > deadline or len(best_g) > MAX_STATES):
            return time.perf_counter() - start, incumbent, False
        for cg, cused, ctypes, copen in children(g, used, used_types, open_needs):
            if not copen:
                incumbent = min(incumbent, cg)
                continue
            cf = cg + bound(copen, ctypes)
            if cf >= incumbent:
                continue
            state = (cused, copen)
            if best_g.get(state, cg + 1) <= cg:
                continue
            best_g[state] = cg
            heapq.heappush(heap, (cf, cf - cg, counter, cg, cused, ctypes, copen))
            counter += 1
    return time.perf_counter() - start, incumbent, True


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
    cold = float(fields["cold_micros"]) / 1e6
    explained = float(fields["explained_micros"]) / 1e6
    return float(fields["micros"]) / 1e6, cost, fields["status"] == "Proven", first, cold, explained


def human(seconds):
    if seconds < 1e-5:
        return f"{seconds * 1e6:.1f} µs"
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    if seconds < 1:
        return f"{seconds * 1e3:.1f} ms"
    return f"{seconds:.2f} s"


def main():
    print(
        "| point | seed | components | ours | ours, compiling the domain too | first found "
        "| clingo | HiGHS | Python B&B "
        "| cost: ours / clingo / HiGHS / B&B | fastest proven peer ÷ ours (compiling the domain too) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    failures = 0
    # The smallest ratios, apart for instances with a configuration and
    # without one (every solver proves none; ours can also explain why, timed
    # apart).
    worst = {True: None, False: None}
    worst_cold = {True: None, False: None}
    # Without a configuration: the ratio when ours also explains why.
    worst_explained = None
    least = lambda a, b: b if a is None else min(a, b)
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
                t_ours, c_ours, p_ours, first, t_cold, t_explained = ours(d)
                comps, chan, user = read_instance(d)
                peers = [
                    median_run(clingo_once, asp_program(comps, chan, user)),
                    median_run(highs_once, comps, chan, user),
                    median_run(bnb_once, comps, chan, user),
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
                    cold_ratio = min(proven_times) / t_cold
                    feasible = c_ours is not None
                    worst[feasible] = least(worst[feasible], ratio)
                    worst_cold[feasible] = least(worst_cold[feasible], cold_ratio)
                    if not feasible:
                        worst_explained = least(worst_explained, min(proven_times) / t_explained)
                    times = lambda r: f"{r:.1f}×" if r < 9.95 else f"{r:.0f}×"
                    ratio_text = f"{times(ratio)} ({times(cold_ratio)})"
                else:
                    fastest = min(t for t, _, _ in peers)
                    ratio_text = f"> {fastest / t_ours:.0f}× (no peer proved)"
                timing = lambda t, proven: f"{human(t)}{'' if proven else ' (not proven)'}"
                why = f"; {human(t_explained)} explaining why" if c_ours is None and p_ours else ""
                print(
                    f"| {label} | {seed} | {len(comps) + 1} | {timing(t_ours, p_ours)}{why} | {human(t_cold)} "
                    f"| {'-' if first is None else human(first)} "
                    f"| {' | '.join(timing(t, pr) for t, _, pr in peers)} "
                    f"| {' / '.join([mark(c_ours, p_ours)] + [mark(c, pr) for _, c, pr in peers])}"
                    f"{'' if agree else ' DISAGREE'} | {ratio_text} |",
                    flush=True,
                )
    print()
    shown = lambda r: "-" if r is None else f"{r:.1f}×"
    print(f"`?`: not proven optimal within the budget of {TIMEOUT_S:.0f} s per solver and instance. "
          f"Smallest ratio where a peer proved, on instances with a configuration: {shown(worst[True])} "
          f"(compiling the domain too: {shown(worst_cold[True])}); "
          f"on instances without one: {shown(worst[False])} "
          f"(compiling the domain too: {shown(worst_cold[False])}; explaining why: {shown(worst_explained)})")
    if failures:
        print(f"{failures} disagreements between proven optima", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
