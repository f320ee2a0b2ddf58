"""Side-by-side benchmark of the action planner against Fast Downward.

Run through `scripts/bench-actions`, which builds the `solve` example of
ecology-actions and installs Fast Downward (`up-fast-downward` from PyPI)
into a virtual environment. The example writes each generated problem
(gripper, blocks world, logistics with action costs) to PDDL files; both
planners then solve the same files, each as a process of its own:

- optimal: ours `--optimal` (A* with LM-cut) against `astar(lmcut())`;
- satisficing: ours (greedy best-first, FF, preferred operators) against
  `--alias lama-first`.

With `BENCH_IPC`, the problems are instead those of the IPC benchmark
collection as Fast Downward's users know it (laid out as the public
`aibasel/downward-benchmarks` repository): `BENCH_IPC=DIR` reads a copy in
DIR, `BENCH_IPC=fetch` clones it into `target/downward-benchmarks` first.
The domains are the suite `optimal_strips` of its `suites.py` (or
`BENCH_IPC_DOMAINS`, names separated by spaces), and the first
`BENCH_IPC_PROBLEMS` (5) problems of each. The summary counts coverage: how
many each planner solved, and for satisficing how many of ours were within
2x Fast Downward's time and 1.25x its cost.

Times are wall-clock times of the whole process, measured here the same way
for both: reading and parsing the files, grounding (Fast Downward: its
Python translator) and search. `search s` is the search alone, as each
planner reports it; expansions per second are taken over it. Optimal costs
must agree; the script fails otherwise (and on an invalid plan of ours).
"""

import ast
import os
import re
import signal
import subprocess
import sys
import tempfile
import importlib.util
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SOLVE = os.environ.get(
    "SOLVE_EXAMPLE", os.path.join(ROOT, "target", "release", "examples", "solve")
)
# The package's own module imports unified_planning, which the driver does not need.
FD = os.path.join(
    importlib.util.find_spec("up_fast_downward").submodule_search_locations[0],
    "downward", "fast-downward.py",
)
TIMEOUT_S = float(os.environ.get("BENCH_TIMEOUT_S", "60"))
ONLY = re.compile(os.environ.get("BENCH_ONLY", ""))
MODES = os.environ.get("BENCH_MODES", "optimal satisficing").split()

PROBLEMS = [
    "gripper-4", "gripper-6", "gripper-8", "gripper-10",
    "blocks-8", "blocks-10", "blocks-12", "blocks-14",
    "logistics-2-4", "logistics-3-4", "logistics-3-5", "logistics-4-5",
]
LARGE = [
    "gripper-12", "gripper-20", "gripper-40",
    "blocks-16", "blocks-20", "blocks-30",
    "logistics-4-6", "logistics-5-6", "logistics-6-8", "logistics-10-16",
]
if os.environ.get("BENCH_LARGE"):
    PROBLEMS += LARGE

IPC = os.environ.get("BENCH_IPC")
IPC_URL = "https://github.com/aibasel/downward-benchmarks"
IPC_PROBLEMS = int(os.environ.get("BENCH_IPC_PROBLEMS", "5"))


def ipc_root():
    """The folder of the IPC collection: BENCH_IPC, or a clone made for `fetch`."""
    if IPC != "fetch":
        if not os.path.isdir(IPC):
            raise SystemExit(f"BENCH_IPC={IPC}: no such folder")
        return IPC
    dest = os.path.join(ROOT, "target", "downward-benchmarks")
    if not os.path.isdir(dest):
        print(f"cloning {IPC_URL} into {dest} ...", file=sys.stderr, flush=True)
        done = subprocess.run(["git", "clone", "--quiet", "--depth", "1", IPC_URL, dest])
        if done.returncode != 0:
            raise SystemExit(f"cannot clone {IPC_URL}: clone it where you can "
                             "and set BENCH_IPC to its folder")
    return dest


def ipc_domain_file(folder, problem):
    """The domain file of `problem` in `folder`: its own (pNN-domain.pddl, domain_pNN.pddl, ...)
    or the folder's domain.pddl."""
    stem = problem[:-len(".pddl")]
    prefix = stem.split("-")[0]
    for name in (f"{stem}-domain.pddl", f"domain_{stem}.pddl", f"domain-{stem}.pddl",
                 f"{prefix}-domain.pddl", f"domain_{prefix}.pddl", "domain.pddl"):
        if os.path.isfile(os.path.join(folder, name)):
            return os.path.join(folder, name)
    return None


def ipc_problems():
    """(name, domain file, problem file) for the first problems of each IPC domain."""
    root = ipc_root()
    names = os.environ.get("BENCH_IPC_DOMAINS", "").split()
    if not names:
        listed = subprocess.run([sys.executable, os.path.join(root, "suites.py"), "optimal_strips"],
                                capture_output=True, text=True, check=True)
        names = ast.literal_eval(listed.stdout.strip())
    out = []
    for domain in names:
        folder = os.path.join(root, domain)
        if not os.path.isdir(folder):
            raise SystemExit(f"{folder}: no such domain folder")
        problems = sorted(f for f in os.listdir(folder)
                          if f.endswith(".pddl") and "domain" not in f)[:IPC_PROBLEMS]
        for problem in problems:
            domain_file = ipc_domain_file(folder, problem)
            if domain_file is None:
                raise SystemExit(f"{folder}/{problem}: no domain file found")
            name = f"{domain}/{problem[:-len('.pddl')]}"
            if ONLY.search(name):
                out.append((name, domain_file, os.path.join(folder, problem)))
    return out


def timed(cmd, cwd):
    """Runs `cmd`; (seconds, stdout, timed_out). Kills its process group on timeout."""
    start = time.perf_counter()
    proc = subprocess.Popen(
        cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True,
    )
    try:
        out, _ = proc.communicate(timeout=TIMEOUT_S)
        return time.perf_counter() - start, out, False
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        return time.perf_counter() - start, out, True


def ours(domain, problem, optimal, cwd):
    cmd = [SOLVE, "run", domain, problem, "--timeout-s", str(TIMEOUT_S)]
    if optimal:
        cmd.append("--optimal")
    secs, out, timed_out = timed(cmd, cwd)
    line = out.strip().splitlines()[-1] if out.strip() else ""
    fields = dict(kv.split("=", 1) for kv in line.split() if "=" in kv)
    if not timed_out and "status" not in fields:
        # Refused (a construct not read, say): shown as such, and said on stderr.
        print(f"ours on {problem}: {out.strip()[:300]}", file=sys.stderr, flush=True)
        return {"secs": secs, "cost": None, "expanded": None, "search": None, "error": True}
    if timed_out or fields.get("status") != "found":
        return {"secs": secs, "cost": None, "expanded": fields.get("expanded"), "search": None}
    if fields.get("valid") != "true":
        raise SystemExit(f"our plan for {problem} is invalid: {line}")
    search = (float(fields["ms"]) - float(fields["ground_ms"])) / 1000
    return {"secs": secs, "cost": int(fields["cost"]), "expanded": int(fields["expanded"]),
            "search": search}


def fd(domain, problem, optimal, cwd):
    cmd = [sys.executable, FD]
    if optimal:
        cmd += [domain, problem, "--search", "astar(lmcut())"]
    else:
        cmd += ["--alias", "lama-first", domain, problem]
    secs, out, timed_out = timed(cmd, cwd)
    cost = re.search(r"Plan cost: (\d+)", out)
    expanded = re.findall(r"Expanded (\d+) state", out)
    search = re.search(r"Search time: ([\d.]+)s", out)
    if timed_out or cost is None:
        return {"secs": secs, "cost": None, "expanded": expanded[-1] if expanded else None,
                "search": None}
    return {"secs": secs, "cost": int(cost.group(1)), "expanded": int(expanded[-1]),
            "search": float(search.group(1)) if search else None}


def human(seconds):
    if seconds is None:
        return "-"
    if seconds < 1:
        return f"{seconds * 1e3:.0f} ms"
    return f"{seconds:.2f} s"


def rate(r):
    if r["cost"] is None or not r["search"]:
        return "-"
    return f"{r['expanded'] / r['search']:,.0f}"


def cell(r):
    if r.get("error"):
        return "error"
    return human(r["secs"]) if r["cost"] is not None else f"> {TIMEOUT_S:.0f} s"


def main():
    failures = []
    worst = {}
    # Per mode: problems tried, solved by ours, by FD; satisficing: ours within 2x time and 1.25x cost.
    coverage = {}
    with tempfile.TemporaryDirectory() as tmp:
        if IPC:
            tasks = ipc_problems()
        else:
            names = [p for p in PROBLEMS if ONLY.search(p)]
            subprocess.run([SOLVE, "write", tmp, *names], check=True)
            tasks = [(name, os.path.join(tmp, f"{name.split('-')[0]}-domain.pddl"),
                      os.path.join(tmp, f"{name}.pddl")) for name in names]
        for mode in MODES:
            optimal = mode == "optimal"
            tally = coverage.setdefault(mode, {"tried": 0, "ours": 0, "fd": 0, "close": 0})
            print()
            if optimal:
                print("Optimal: ours (A*, LM-cut) against Fast Downward `astar(lmcut())`.")
                print()
                print("| problem | cost | ours | FD | ours ÷ FD | ours search | FD search "
                      "| expanded: ours / FD | expanded/s: ours / FD |")
                print("|---|---|---|---|---|---|---|---|---|")
            else:
                print("Satisficing: ours (greedy best-first, FF with preferred operators and the "
                      "landmark count in turn) against "
                      "Fast Downward `--alias lama-first`.")
                print()
                print("| problem | ours | FD | ours ÷ FD | cost: ours / FD | ours cost ÷ FD cost "
                      "| expanded: ours / FD |")
                print("|---|---|---|---|---|---|---|")
            for name, domain, problem in tasks:
                run_dir = os.path.join(tmp, "run-" + name.replace("/", "-") + f"-{mode}")
                os.makedirs(run_dir, exist_ok=True)
                a = ours(domain, problem, optimal, run_dir)
                b = fd(domain, problem, optimal, run_dir)
                tally["tried"] += 1
                tally["ours"] += a["cost"] is not None
                tally["fd"] += b["cost"] is not None
                both = a["cost"] is not None and b["cost"] is not None
                ratio = a["secs"] / b["secs"] if both else None
                if ratio is not None:
                    worst[mode] = max(worst.get(mode, 0), ratio)
                ratio_text = f"{ratio:.2f}" if ratio is not None else "-"
                if optimal:
                    if both and a["cost"] != b["cost"]:
                        failures.append(f"{name}: optimal cost {a['cost']} (ours) != {b['cost']} (FD)")
                    costs = "/".join(sorted({str(c) for c in (a["cost"], b["cost"]) if c is not None})) or "-"
                    if both and a["cost"] != b["cost"]:
                        costs = f"{a['cost']} != {b['cost']} DISAGREE"
                    print(f"| {name} | {costs} | {cell(a)} | {cell(b)} | {ratio_text} "
                          f"| {human(a['search'])} | {human(b['search'])} "
                          f"| {a['expanded'] or '-'} / {b['expanded'] or '-'} | {rate(a)} / {rate(b)} |",
                          flush=True)
                else:
                    cost_ratio = f"{a['cost'] / b['cost']:.2f}" if both and b["cost"] else "-"
                    if both and b["cost"]:
                        worst["cost"] = max(worst.get("cost", 0), a["cost"] / b["cost"])
                    if a["cost"] is not None and (
                            b["cost"] is None
                            or (a["secs"] <= 2 * b["secs"] and a["cost"] <= 1.25 * b["cost"])):
                        tally["close"] += 1
                    print(f"| {name} | {cell(a)} | {cell(b)} | {ratio_text} "
                          f"| {a['cost'] if a['cost'] is not None else '-'} / "
                          f"{b['cost'] if b['cost'] is not None else '-'} | {cost_ratio} "
                          f"| {a['expanded'] or '-'} / {b['expanded'] or '-'} |", flush=True)
    print()
    for mode, t in coverage.items():
        line = f"{mode}: solved {t['ours']} of {t['tried']} (ours), {t['fd']} (FD)"
        if mode != "optimal":
            line += (f"; ours within 2x FD's time and 1.25x its cost (or solved where FD did not): "
                     f"{t['close']}")
        print(line)
    print()
    print(f"Timeout {TIMEOUT_S:.0f} s per planner and run. Largest ours ÷ FD time where both solved: "
          + ", ".join(f"{k} {v:.2f}" for k, v in worst.items()))
    if failures:
        for f in failures:
            print(f, file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
